"""Control: repulsion, joint-velocity limits, SNS, closed loop, motion verdicts (R13-R15, R22, R27)."""
