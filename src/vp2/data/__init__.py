"""Data: scripted policies, trajectory collection, datasets and the task suite."""
