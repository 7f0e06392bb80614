"""Model checking: explicit-state CTL with fairness and knowledge, look-compute-move robot models, launch graphs."""
