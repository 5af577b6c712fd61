"""The values every stage speaks: errors, bounds on outside input, the command line's choices, the
pipeline's estimate, the pad's state, the sensor's geometry, a run's counters, atomic output files."""
