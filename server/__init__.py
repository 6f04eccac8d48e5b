"""ippc.server."""
