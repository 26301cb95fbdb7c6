"""Speed benchmarks: how long a step, a render, a forward pass or a metric takes."""
