"""``python -m scenarios score CONTROLLER``: a controller's verdicts and figures on a fixed battery, beside ours.

:mod:`.battery` the cases and one run; :mod:`.run` the battery on Dask (or in this process); :mod:`.baseline` the
committed baseline file of our controllers; :mod:`.page` the HTML page, its figures and the JSON; :mod:`.cli`
the command. docs/score.md says what the page shows.
"""
