"""Small shared utilities (files, seeding, parallel execution)."""
