"""Recordings in and out: CSV and MCAP bags (writer, reader, recovery), SI columns."""
