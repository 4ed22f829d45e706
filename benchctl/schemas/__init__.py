"""Versioned JSON Schemas of benchctl's outputs (``record-1.schema.json``: ``record.json``)."""
