"""Fidelity checks: vp2's re-implementations against the originals they replace."""
