"""The robot actor process: a simulator slice that streams experience and learns per-robot Q tables."""
