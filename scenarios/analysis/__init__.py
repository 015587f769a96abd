"""Models a run is checked against: the linearised sampled loop, the plant schemes' limits on the bracket modes,
the metrics' predicted deviation."""
