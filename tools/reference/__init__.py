"""Reference pages generated from the code, so that they say what it does: the configuration reference
(:mod:`tools.reference.configuration`, ``docs/reference/configuration.md``)."""
