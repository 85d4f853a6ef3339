"""Per-camera filtering: the expected depth of the known scene (R9, R16, R17)."""

from depthguard.filtering.expected import ExpectedDepth

__all__ = ["ExpectedDepth"]
