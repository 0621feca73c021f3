//! `ros2msg` schema texts: each type's `.msg` definition followed by every type it uses,
//! each after a line of 80 `=` and a `MSG: pkg/Type` line, as rosbag2's MCAP writer
//! stores them, so Foxglove and the `mcap-ros2-support` decoder read our channels.

/// A ROS 2 message type this module can describe.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct RosType {
    /// `pkg/Type` (the name dependent sections use).
    pub short: &'static str,
    /// The `.msg` text.
    pub text: &'static str,
    /// Types the text refers to, directly.
    pub deps: &'static [&'static RosType],
}

impl RosType {
    /// The schema name rosbag2 uses: `pkg/msg/Type`.
    pub fn schema_name(&self) -> String {
        match self.short.split_once('/') {
            Some((pkg, ty)) => format!("{pkg}/msg/{ty}"),
            None => self.short.to_string(),
        }
    }

    /// The complete `ros2msg` definition: this type's text, then each dependency (depth
    /// first, each once).
    pub fn full_definition(&self) -> String {
        let mut seen: Vec<&'static str> = Vec::new();
        let mut out = String::from(self.text);
        fn visit(t: &RosType, seen: &mut Vec<&'static str>, out: &mut String) {
            for d in t.deps {
                if seen.contains(&d.short) {
                    continue;
                }
                seen.push(d.short);
                out.push('\n');
                out.push_str(&"=".repeat(80));
                out.push_str("\nMSG: ");
                out.push_str(d.short);
                out.push('\n');
                out.push_str(d.text);
                visit(d, seen, out);
            }
        }
        visit(self, &mut seen, &mut out);
        out
    }
}

/// `builtin_interfaces/Time`.
pub static TIME: RosType = RosType {
    short: "builtin_interfaces/Time",
    text: "int32 sec\nuint32 nanosec\n",
    deps: &[],
};
/// `std_msgs/Header`.
pub static HEADER: RosType = RosType {
    short: "std_msgs/Header",
    text: "builtin_interfaces/Time stamp\nstring frame_id\n",
    deps: &[&TIME],
};
/// `geometry_msgs/Quaternion`.
pub static QUATERNION: RosType = RosType {
    short: "geometry_msgs/Quaternion",
    text: "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    deps: &[],
};
/// `geometry_msgs/Vector3`.
pub static VECTOR3: RosType = RosType {
    short: "geometry_msgs/Vector3",
    text: "float64 x\nfloat64 y\nfloat64 z\n",
    deps: &[],
};
/// `geometry_msgs/Point`.
pub static POINT: RosType = RosType {
    short: "geometry_msgs/Point",
    text: "float64 x\nfloat64 y\nfloat64 z\n",
    deps: &[],
};
/// `geometry_msgs/Pose`.
pub static POSE: RosType = RosType {
    short: "geometry_msgs/Pose",
    text: "Point position\nQuaternion orientation\n",
    deps: &[&POINT, &QUATERNION],
};
/// `geometry_msgs/PoseWithCovariance`.
pub static POSE_WITH_COVARIANCE: RosType = RosType {
    short: "geometry_msgs/PoseWithCovariance",
    text: "Pose pose\nfloat64[36] covariance\n",
    deps: &[&POSE],
};
/// `geometry_msgs/Twist`.
pub static TWIST: RosType = RosType {
    short: "geometry_msgs/Twist",
    text: "Vector3 linear\nVector3 angular\n",
    deps: &[&VECTOR3],
};
/// `geometry_msgs/TwistWithCovariance`.
pub static TWIST_WITH_COVARIANCE: RosType = RosType {
    short: "geometry_msgs/TwistWithCovariance",
    text: "Twist twist\nfloat64[36] covariance\n",
    deps: &[&TWIST],
};
/// `geometry_msgs/TwistWithCovarianceStamped`.
pub static TWIST_WITH_COVARIANCE_STAMPED: RosType = RosType {
    short: "geometry_msgs/TwistWithCovarianceStamped",
    text: "std_msgs/Header header\nTwistWithCovariance twist\n",
    deps: &[&HEADER, &TWIST_WITH_COVARIANCE],
};
/// `geometry_msgs/Transform`.
pub static TRANSFORM: RosType = RosType {
    short: "geometry_msgs/Transform",
    text: "Vector3 translation\nQuaternion rotation\n",
    deps: &[&VECTOR3, &QUATERNION],
};
/// `geometry_msgs/TransformStamped`.
pub static TRANSFORM_STAMPED: RosType = RosType {
    short: "geometry_msgs/TransformStamped",
    text: "std_msgs/Header header\nstring child_frame_id\nTransform transform\n",
    deps: &[&HEADER, &TRANSFORM],
};
/// `tf2_msgs/TFMessage`.
pub static TF_MESSAGE: RosType = RosType {
    short: "tf2_msgs/TFMessage",
    text: "geometry_msgs/TransformStamped[] transforms\n",
    deps: &[&TRANSFORM_STAMPED],
};
/// `nav_msgs/Odometry`.
pub static ODOMETRY: RosType = RosType {
    short: "nav_msgs/Odometry",
    text: "std_msgs/Header header\nstring child_frame_id\n\
           geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
    deps: &[&HEADER, &POSE_WITH_COVARIANCE, &TWIST_WITH_COVARIANCE],
};
/// `sensor_msgs/Imu`.
pub static IMU: RosType = RosType {
    short: "sensor_msgs/Imu",
    text: "std_msgs/Header header\n\
           geometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n\
           geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n\
           geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n",
    deps: &[&HEADER, &QUATERNION, &VECTOR3],
};
/// `sensor_msgs/NavSatStatus`.
pub static NAV_SAT_STATUS: RosType = RosType {
    short: "sensor_msgs/NavSatStatus",
    text: "int8 STATUS_NO_FIX = -1\nint8 STATUS_FIX = 0\nint8 STATUS_SBAS_FIX = 1\n\
           int8 STATUS_GBAS_FIX = 2\nint8 status\n\
           uint16 SERVICE_GPS = 1\nuint16 SERVICE_GLONASS = 2\nuint16 SERVICE_COMPASS = 4\n\
           uint16 SERVICE_GALILEO = 8\nuint16 service\n",
    deps: &[],
};
/// `sensor_msgs/NavSatFix`.
pub static NAV_SAT_FIX: RosType = RosType {
    short: "sensor_msgs/NavSatFix",
    text: "std_msgs/Header header\nNavSatStatus status\n\
           float64 latitude\nfloat64 longitude\nfloat64 altitude\n\
           float64[9] position_covariance\n\
           uint8 COVARIANCE_TYPE_UNKNOWN = 0\nuint8 COVARIANCE_TYPE_APPROXIMATED = 1\n\
           uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2\nuint8 COVARIANCE_TYPE_KNOWN = 3\n\
           uint8 position_covariance_type\n",
    deps: &[&HEADER, &NAV_SAT_STATUS],
};
/// `gps_msgs/GPSStatus` (ROS 2 `gps_umd`).
pub static GPS_STATUS: RosType = RosType {
    short: "gps_msgs/GPSStatus",
    text: "std_msgs/Header header\n\
           uint16 satellites_used\nint32[] satellite_used_prn\n\
           uint16 satellites_visible\nint32[] satellite_visible_prn\n\
           int32[] satellite_visible_z\nint32[] satellite_visible_azimuth\n\
           int32[] satellite_visible_snr\n\
           int16 STATUS_NO_FIX=-1\nint16 STATUS_FIX=0\nint16 STATUS_SBAS_FIX=1\n\
           int16 STATUS_GBAS_FIX=2\nint16 STATUS_DGPS_FIX=18\nint16 STATUS_RTK_FIX=19\n\
           int16 STATUS_RTK_FLOAT=20\nint16 STATUS_WAAS_FIX=33\nint16 status\n\
           uint16 SOURCE_NONE=0\nuint16 SOURCE_GPS=1\nuint16 SOURCE_POINTS=2\n\
           uint16 SOURCE_DOPPLER=4\nuint16 SOURCE_ALTIMETER=8\nuint16 SOURCE_MAGNETIC=16\n\
           uint16 SOURCE_GYRO=32\nuint16 SOURCE_ACCEL=64\n\
           uint16 motion_source\nuint16 orientation_source\nuint16 position_source\n",
    deps: &[&HEADER],
};
/// `gps_msgs/GPSFix` (ROS 2 `gps_umd`): the fix with its DOPs and satellites.
pub static GPS_FIX: RosType = RosType {
    short: "gps_msgs/GPSFix",
    text: "std_msgs/Header header\nGPSStatus status\n\
           float64 latitude\nfloat64 longitude\nfloat64 altitude\n\
           float64 track\nfloat64 speed\nfloat64 climb\n\
           float64 pitch\nfloat64 roll\nfloat64 dip\nfloat64 time\n\
           float64 gdop\nfloat64 pdop\nfloat64 hdop\nfloat64 vdop\nfloat64 tdop\n\
           float64 err\nfloat64 err_horz\nfloat64 err_vert\nfloat64 err_track\n\
           float64 err_speed\nfloat64 err_climb\nfloat64 err_time\n\
           float64 err_pitch\nfloat64 err_roll\nfloat64 err_dip\n\
           float64[9] position_covariance\n\
           uint8 COVARIANCE_TYPE_UNKNOWN = 0\nuint8 COVARIANCE_TYPE_APPROXIMATED = 1\n\
           uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2\nuint8 COVARIANCE_TYPE_KNOWN = 3\n\
           uint8 position_covariance_type\n",
    deps: &[&HEADER, &GPS_STATUS],
};
/// `sensor_msgs/Image`.
pub static IMAGE: RosType = RosType {
    short: "sensor_msgs/Image",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
           uint8 is_bigendian\nuint32 step\nuint8[] data\n",
    deps: &[&HEADER],
};
/// `sensor_msgs/RegionOfInterest`.
pub static REGION_OF_INTEREST: RosType = RosType {
    short: "sensor_msgs/RegionOfInterest",
    text: "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
    deps: &[],
};
/// `sensor_msgs/CameraInfo`.
pub static CAMERA_INFO: RosType = RosType {
    short: "sensor_msgs/CameraInfo",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
           float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\n\
           uint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n",
    deps: &[&HEADER, &REGION_OF_INTEREST],
};
/// `sensor_msgs/PointField`.
pub static POINT_FIELD: RosType = RosType {
    short: "sensor_msgs/PointField",
    text: "uint8 INT8 = 1\nuint8 UINT8 = 2\nuint8 INT16 = 3\nuint8 UINT16 = 4\n\
           uint8 INT32 = 5\nuint8 UINT32 = 6\nuint8 FLOAT32 = 7\nuint8 FLOAT64 = 8\n\
           string name\nuint32 offset\nuint8 datatype\nuint32 count\n",
    deps: &[],
};
/// `sensor_msgs/PointCloud2`.
pub static POINT_CLOUD2: RosType = RosType {
    short: "sensor_msgs/PointCloud2",
    text: "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\n\
           bool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
    deps: &[&HEADER, &POINT_FIELD],
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dependencies_follow_the_top_level_text_once_each() {
        let def = ODOMETRY.full_definition();
        assert!(def.starts_with("std_msgs/Header header\n"));
        let sep = format!("\n{}\nMSG: ", "=".repeat(80));
        let sections: Vec<&str> = def.split(&sep).collect();
        let names: Vec<&str> = sections[1..]
            .iter()
            .map(|s| s.lines().next().unwrap_or(""))
            .collect();
        assert_eq!(
            names,
            [
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/PoseWithCovariance",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "geometry_msgs/TwistWithCovariance",
                "geometry_msgs/Twist",
                "geometry_msgs/Vector3",
            ]
        );
        assert_eq!(IMU.schema_name(), "sensor_msgs/msg/Imu");
    }
}
