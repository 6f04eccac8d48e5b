"""ippc.dispatch: the robot side (sensing, action handlers, the online dispatcher)."""
