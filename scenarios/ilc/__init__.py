"""Iterative learning control through the FMUs: the ILC scenarios, their trials and the floor of their error."""
