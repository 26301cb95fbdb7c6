"""Studies: one question each about the models, the cost, the planner or the task suite."""
