"""Sources of this project's FMUs (the wrappers and their C front end), read by :mod:`fmu_build`.

Not imported as a package at run time: each FMU bundles its files and imports them by their
top-level module names. This file makes the folder installable as package data.
"""
