"""Reactions to distances: repulsion (R13), joint-velocity limits (R14), SNS, the supervisor (R26, R27), motion verdicts (R22)."""
