"""clis_learner: episode memory, resampling, importance-sampled updates, the learner node."""
