"""ROS 2 message definitions (the text an MCAP file embeds) written out by hand, for the
independent writer (``mcap_ros2.writer``) in the bag tests — not taken from depthguard or
rosbags, so that a bag written with them is foreign to both."""

_SEP = "\n" + "=" * 80 + "\n"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id"
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
IMAGE_DEF = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
             "uint32 step\nuint8[] data" + _SEP + _HEADER + _SEP + _TIME)
INFO_DEF = ("std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\n"
            "float64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\n"
            "sensor_msgs/RegionOfInterest roi" + _SEP + _HEADER + _SEP + _TIME + _SEP +
            "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify")
JOINT_DEF = ("std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort"
             + _SEP + _HEADER + _SEP + _TIME)
TF_DEF = ("geometry_msgs/TransformStamped[] transforms" + _SEP +
          "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform"
          + _SEP + _HEADER + _SEP + _TIME + _SEP +
          "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation" + _SEP +
          "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z" + _SEP +
          "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1")


def _stamp(s: float) -> dict:
    ns = round(s * 1e9)
    return {"sec": ns // 10**9, "nanosec": ns % 10**9}
