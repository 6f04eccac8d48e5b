"""ippc.client."""
