"""A scenario's run: choosing the FMUs, setting up the loop, running its cases, judging and writing the results."""
