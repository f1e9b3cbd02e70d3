"""The wire contract: topics, schema names and JSON Schemas of every message published and recorded."""
