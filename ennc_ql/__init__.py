"""Composition root of ennc-ql: the command line, configuration loading, launchers and experiment commands."""
