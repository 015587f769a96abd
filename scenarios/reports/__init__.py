"""Generators of documents: the results page and every generated block in README.md and docs/*.md."""
