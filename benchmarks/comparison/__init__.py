"""The model comparison: train, measure and plan with every model family, then publish."""
