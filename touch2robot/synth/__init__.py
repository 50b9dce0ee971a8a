"""The simulated demonstrator (the embedded default source of recordings)."""
