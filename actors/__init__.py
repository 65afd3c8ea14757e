"""Robot actors: simulator slices that run learning trials, collect experience and learn per-robot Q tables."""
