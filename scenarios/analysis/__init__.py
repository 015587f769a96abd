"""Models a run is checked against: the linearised sampled loop, the plant schemes' limits, the metrics' expected deviation."""
