"""Recordings on disk: CDR message codec and MCAP writer (the reader side is ingestion)."""
