"""Checks of the project itself: a snapshot of vp2's behaviour, to diff across a change."""
