"""How the processes of a cell talk: Zenoh session settings and key names (``settings``), the
fusion server's wire format (``wire``), its request-reply client (``client``), the cell's
certificates and signed requests (``keys``, ``auth``, R35), and ROS 2 over Zenoh — topic and
node names, the rmw_zenoh key expressions (``ros2_zenoh``) and the CDR messages
(``ros_messages``, R20, R31).

It sits below every room that talks (sources, runtime, distributed, cli): the camera units
and the fusion server (:mod:`depthguard.distributed`) and the sources and sinks that reach
them use the same helpers without importing each other.
"""
