"""Runtime example and utility nodes (relays, counters, transport benchmark peers)."""
