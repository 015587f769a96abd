"""The co-simulation master and what drives FMUs: instances, callbacks, values, processes of their own, signals."""
