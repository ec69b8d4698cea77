"""Read-only checks on an assembled model: interconnection graph and certificates."""
