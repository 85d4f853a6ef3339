"""Distributed camera subsystem over zenoh (Oščádal 2022, R20).

``wire`` (binary messages), ``settings`` (zenoh config, key names), ``server``
(:class:`~depthguard.distributed.server.FusionServer`), ``node``
(:class:`~depthguard.distributed.node.CameraNode`), ``client`` (request-reply),
``central`` (the centralised pipeline for comparison). Import the submodules
directly; this file stays light.
"""
