use super::*;
use nalgebra::Vector3;

fn tracked() -> RobotModel {
    RobotModel::builtin("tracked-sensorbox").unwrap()
}

fn rover() -> RobotModel {
    RobotModel::builtin("mecanum-rover").unwrap()
}

#[test]
fn builtin_tracked_robot_resolves_sensor_frames() {
    let r = tracked();
    assert!((r.geometry.track_width_m - 0.6).abs() < 1e-12);
    assert!((r.geometry.ride_height_m - 0.18).abs() < 1e-12);
    assert!((r.geometry.footprint_length_m - 1.1).abs() < 1e-12);
    assert!((r.geometry.footprint_width_m - 0.8).abs() < 1e-12);
    // imu_link = sensor_frame (0.30, 0, 0.18) + sensor_box (0, 0, 0.62) + (-0.04, 0.02, -0.03)
    let imu = r.body_from("imu_link").unwrap();
    assert!((imu.translation.vector - Vector3::new(0.26, 0.02, 0.77)).norm() < 1e-12);
    // The optical frame looks forward (z) with x to the right (-y of the body).
    let opt = r.body_from("camera_center_color_optical_frame").unwrap();
    assert!((opt.rotation * Vector3::z() - Vector3::x()).norm() < 1e-12);
    assert!((opt.rotation * Vector3::x() + Vector3::y()).norm() < 1e-12);
    // The side cameras are yawed by ±30.5°.
    let left = r.body_from("camera_left_link").unwrap();
    assert!(
        ((left.rotation * Vector3::x())
            .y
            .atan2((left.rotation * Vector3::x()).x)
            .to_degrees()
            - 30.5)
            .abs()
            < 1e-9
    );
    // Sprockets turn, so they are not static transforms.
    assert!(r.static_transforms.body_from("left_sprocket").is_none());
    assert!(r.static_transforms.body_from("left_track").is_some());
}

#[test]
fn tracked_drive_comes_from_the_gazebo_blocks_and_joint_limits() {
    let r = tracked();
    let Drive::Tracked(t) = &r.drive else {
        panic!("tracked drive expected, got {}", r.drive.kind_name())
    };
    for (track, y) in [(&t.left, 0.3), (&t.right, -0.3)] {
        assert!(
            (track.body_from_track.translation.vector - Vector3::new(0.0, y, -0.08)).norm() < 1e-12
        );
        assert_eq!(
            (track.length_m, track.width_m, track.height_m),
            (1.1, 0.2, 0.2)
        );
        let s = &track.sprocket;
        assert_eq!(s.radius_m, 0.1);
        // Sprocket 0.015 kg·m² plus the rotor reflected through the 40:1 gear.
        assert!((s.inertia_kgm2 - (0.015 + 1.5e-4 * 40.0 * 40.0)).abs() < 1e-12);
        assert_eq!(
            (s.max_torque_nm, s.max_speed_radps, s.max_accel_radps2),
            (80.0, 15.0, 20.0)
        );
        assert_eq!((s.damping_nms, s.friction_nm), (0.5, 1.0));
        assert!((s.axis_in_body - Vector3::y()).norm() < 1e-12);
        assert!(
            (s.body_from_joint.translation.vector - Vector3::new(0.45, y, -0.08)).norm() < 1e-12
        );
        let c = &track.contact;
        assert_eq!((c.mu1, c.mu2), (0.8, 0.5));
        assert!((c.fdir1_in_body - Vector3::x()).norm() < 1e-12);
        assert_eq!(
            (c.stiffness_n_per_m, c.damping_ns_per_m),
            (80_000.0, 2_000.0)
        );
    }
    assert!(!r.drive.is_holonomic());
    assert_eq!(r.drive.joints().len(), 2);
    // Tracks and sprockets are running gear; the chassis box is not.
    for c in &r.collision_shapes {
        assert_eq!(
            c.running_gear,
            c.link.contains("track") || c.link.contains("sprocket"),
            "{}",
            c.link
        );
    }
}

#[test]
fn tracked_mass_properties_sum_every_link() {
    // Hand sum of the URDF's links (mass, centre in base_link):
    // chassis 120 at (0, 0, 0.05); tracks 15 at (0, ±0.3, −0.08); sprockets 3 at
    // (0.45, ±0.3, −0.08); sensor frame 6 at (0.30, 0, 0.18 + 0.3); sensor box 4 at
    // (0.30, 0, 0.18 + 0.62).
    let parts = [
        (120.0, Vector3::new(0.0, 0.0, 0.05)),
        (15.0, Vector3::new(0.0, 0.3, -0.08)),
        (15.0, Vector3::new(0.0, -0.3, -0.08)),
        (3.0, Vector3::new(0.45, 0.3, -0.08)),
        (3.0, Vector3::new(0.45, -0.3, -0.08)),
        (6.0, Vector3::new(0.30, 0.0, 0.48)),
        (4.0, Vector3::new(0.30, 0.0, 0.80)),
    ];
    let m: f64 = parts.iter().map(|p| p.0).sum();
    let com = parts.iter().fold(Vector3::zeros(), |a, p| a + p.1 * p.0) / m;
    let r = tracked();
    assert!((r.inertia.mass_kg - 166.0).abs() < 1e-12);
    assert!(
        (r.inertia.com_in_body - com).norm() < 1e-12,
        "{:?}",
        r.inertia.com_in_body
    );
    // izz about the COM: the links' own izz plus m·(dx² + dy²).
    let own_izz = 12.1 + 2.0 * 1.56 + 2.0 * 0.0175 + 0.02 + 0.04;
    let izz = own_izz
        + parts
            .iter()
            .map(|(mi, c)| mi * ((c.x - com.x).powi(2) + (c.y - com.y).powi(2)))
            .sum::<f64>();
    let i = r.inertia.inertia_about_com_in_body;
    assert!((i[(2, 2)] - izz).abs() < 1e-9, "{} vs {izz}", i[(2, 2)]);
    assert!((i - i.transpose()).norm() < 1e-12);
}

#[test]
fn parallel_axis_sum_matches_two_point_masses() {
    // Two 2 kg links with negligible own inertia at x = ±0.5 m: about the common centre
    // Iyy = Izz = 2·2·0.5² = 1 kg·m², Ixx ≈ 0.
    let urdf = format!(
        r#"<robot name="dumbbell" version="1.2">
  <link name="base_link"/>
  <link name="base_footprint"/>
  <joint name="f" type="fixed"><parent link="base_link"/><child link="base_footprint"/><origin xyz="0 0 -0.1"/></joint>
  <link name="a"><inertial><mass value="2"/><inertia ixx="1e-9" iyy="1e-9" izz="1e-9" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="b"><inertial><origin xyz="-0.5 0 0" rpy="0.3 0.2 0.1"/><mass value="2"/><inertia ixx="1e-9" iyy="1e-9" izz="1e-9" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="ja" type="fixed"><parent link="base_link"/><child link="a"/><origin xyz="0.5 0 0"/></joint>
  <joint name="jb" type="fixed"><parent link="base_link"/><child link="b"/></joint>
  {}
</robot>"#,
        MINIMAL_TRACKS
    );
    let r = RobotModel::from_urdf_str(&urdf, "dumbbell.urdf").unwrap();
    // With the minimal drive's 4 × 1 kg (tracks at (0, ±0.3, −0.05), sprockets at
    // (0.2, ±0.3, −0.05), own Iyy 0.01 each): point masses (m, x, z).
    let points = [
        (2.0, 0.5, 0.0),
        (2.0, -0.5, 0.0),
        (1.0, 0.0, -0.05),
        (1.0, 0.0, -0.05),
        (1.0, 0.2, -0.05),
        (1.0, 0.2, -0.05),
    ];
    let m: f64 = points.iter().map(|p| p.0).sum();
    let (cx, cz) = (
        points.iter().map(|p| p.0 * p.1).sum::<f64>() / m,
        points.iter().map(|p| p.0 * p.2).sum::<f64>() / m,
    );
    assert!((r.inertia.mass_kg - m).abs() < 1e-12);
    assert!((r.inertia.com_in_body - Vector3::new(cx, 0.0, cz)).norm() < 1e-12);
    let iyy = points
        .iter()
        .map(|(mi, x, z)| mi * ((x - cx).powi(2) + (z - cz).powi(2)))
        .sum::<f64>()
        + 4.0 * 0.01;
    let i = r.inertia.inertia_about_com_in_body;
    assert!((i[(1, 1)] - iyy).abs() < 1e-8, "{} vs {iyy}", i[(1, 1)]);
}

/// A valid tracked drive with 1 kg tracks and sprockets, for synthetic robots.
const MINIMAL_TRACKS: &str = r#"
  <link name="lt"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><box size="0.5 0.1 0.1"/></geometry></collision></link>
  <link name="rt"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><box size="0.5 0.1 0.1"/></geometry></collision></link>
  <joint name="jlt" type="fixed"><parent link="base_link"/><child link="lt"/><origin xyz="0 0.3 -0.05"/></joint>
  <joint name="jrt" type="fixed"><parent link="base_link"/><child link="rt"/><origin xyz="0 -0.3 -0.05"/></joint>
  <link name="ls"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <link name="rs"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision></link>
  <joint name="jls" type="continuous"><parent link="lt"/><child link="ls"/><origin xyz="0.2 0 0"/><axis xyz="0 1 0"/><limit effort="10" velocity="5"/></joint>
  <joint name="jrs" type="continuous"><parent link="rt"/><child link="rs"/><origin xyz="0.2 0 0"/><axis xyz="0 1 0"/><limit effort="10" velocity="5"/></joint>
  <gazebo reference="lt"><mu1>0.8</mu1><mu2>0.5</mu2><fdir1>1 0 0</fdir1><kp>1000</kp><kd>10</kd></gazebo>
  <gazebo reference="rt"><mu1>0.8</mu1><mu2>0.5</mu2><fdir1>1 0 0</fdir1><kp>1000</kp><kd>10</kd></gazebo>
  <gazebo><plugin filename="gz-sim-tracked-vehicle-system" name="gz::sim::systems::TrackedVehicle">
    <left_track><link>lt</link></left_track><right_track><link>rt</link></right_track>
  </plugin></gazebo>"#;

#[test]
fn mecanum_rover_drive_geometry_and_frames() {
    let r = rover();
    let Drive::Mecanum(m) = &r.drive else {
        panic!("mecanum drive expected")
    };
    let names: Vec<&str> = m.wheels.iter().map(|w| w.joint.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "front_left_wheel_joint",
            "front_right_wheel_joint",
            "rear_left_wheel_joint",
            "rear_right_wheel_joint"
        ]
    );
    assert!(r.drive.is_holonomic());
    assert_eq!(
        r.drive.kinematics(),
        DriveKinematics::Mecanum {
            half_wheelbase_m: 0.2,
            half_separation_m: 0.22,
            wheel_radius_m: 0.0508
        }
    );
    for w in &m.wheels {
        // Wheel 7.74e-4 kg·m² plus the RE 35 rotor through the 26:1 gear.
        assert!((w.joint.inertia_kgm2 - (7.74e-4 + 6.52e-6 * 26.0 * 26.0)).abs() < 1e-12);
        assert_eq!(w.joint.max_torque_nm, 5.0);
        assert_eq!(w.width_m, 0.05);
        assert_eq!((w.contact.mu1, w.contact.mu2), (0.9, 0.0));
        // Rollers at 45° to the wheel's rolling direction.
        assert!((w.contact.fdir1_in_body.x.abs() - 0.5f64.sqrt()).abs() < 1e-12);
    }
    assert!((r.inertia.mass_kg - 24.082).abs() < 1e-9);
    assert!((r.geometry.ride_height_m - 0.0508).abs() < 1e-12);
    // Cameras: 12 cm stereo baselines; the rear camera looks backward, the side camera
    // to the right.
    for cam in ["front", "rear"] {
        let l = r
            .body_from(&format!("{cam}_camera_left_optical_frame"))
            .unwrap();
        let rr = r
            .body_from(&format!("{cam}_camera_right_optical_frame"))
            .unwrap();
        assert!(((l.translation.vector - rr.translation.vector).norm() - 0.12).abs() < 1e-12);
    }
    let rear = r.body_from("rear_camera_left_optical_frame").unwrap();
    assert!((rear.rotation * Vector3::z() + Vector3::x()).norm() < 1e-12);
    let side = r.body_from("side_camera_optical_frame").unwrap();
    assert!((side.rotation * Vector3::z() + Vector3::y()).norm() < 1e-12);
    for link in [
        "imu_link",
        "gnss_antenna",
        "front_camera_link",
        "base_footprint",
    ] {
        r.body_from(link).unwrap();
    }
    assert!(r.static_transforms.body_from("front_left_wheel").is_none());
}

#[test]
fn mecanum_rollers_agree_with_the_inverse_kinematics() {
    // For a wheel whose ground-contact rollers lie along u, rolling without slip along u
    // means: (velocity of the contact point)·u = r·w·(x̂·u). The inverse kinematics must
    // satisfy this for every wheel and any body twist, with u = the URDF's fdir1.
    let r = rover();
    let Drive::Mecanum(m) = &r.drive else {
        panic!()
    };
    let k = r.drive.kinematics();
    for (vx, vy, wz) in [
        (1.0, 0.0, 0.0),
        (0.0, 1.0, 0.0),
        (0.0, 0.0, 1.0),
        (0.3, -0.7, 0.4),
    ] {
        let w = k.joint_speeds(vx, vy, wz);
        for (i, wheel) in m.wheels.iter().enumerate() {
            let p = wheel.joint.body_from_joint.translation.vector;
            let v_contact = Vector3::new(vx - wz * p.y, vy + wz * p.x, 0.0);
            let u = wheel.contact.fdir1_in_body;
            let lhs = v_contact.dot(&u);
            let rhs = wheel.joint.radius_m * w[i] * Vector3::x().dot(&u);
            assert!(
                (lhs - rhs).abs() < 1e-12,
                "wheel {i}, twist ({vx}, {vy}, {wz})"
            );
        }
        // And the forward kinematics inverts it.
        let (a, b, c) = k.body_twist(&w);
        assert!((a - vx).abs() < 1e-12 && (b - vy).abs() < 1e-12 && (c - wz).abs() < 1e-12);
    }
    // Skid-steer: forward then back, vy dropped.
    let k = tracked().drive.kinematics();
    let w = k.joint_speeds(0.8, 0.5, -0.3);
    let (a, b, c) = k.body_twist(&w);
    assert!((a - 0.8).abs() < 1e-12 && b == 0.0 && (c + 0.3).abs() < 1e-12);
    assert!((w[0] - (0.8 + 0.3 * 0.3) / 0.1).abs() < 1e-12);
}

fn with(replace: &str, by: &str) -> String {
    let text = BUILTIN_MODELS[0].2;
    assert!(text.contains(replace), "fixture text not found: {replace}");
    text.replacen(replace, by, 1)
}

fn with_rover(replace: &str, by: &str) -> String {
    let text = BUILTIN_MODELS[1].2;
    assert!(text.contains(replace), "fixture text not found: {replace}");
    text.replacen(replace, by, 1)
}

fn error(text: &str) -> String {
    RobotModel::from_urdf_str(text, "bad.urdf")
        .unwrap_err()
        .to_string()
}

#[test]
fn malformed_urdfs_name_file_element_and_expectation() {
    let err = error(&with(
        r#"<origin xyz="-0.04 0.02 -0.03""#,
        r#"<origin xyz="nan 0.02 -0.03""#,
    ));
    assert!(
        err.contains("bad.urdf") && err.contains("imu_joint") && err.contains("finite"),
        "{err}"
    );

    let err = error(&with(
        r#"<parent link="sensor_box"/>
    <child link="imu_link"/>"#,
        r#"<parent link="sensor_boxx"/>
    <child link="imu_link"/>"#,
    ));
    assert!(
        err.contains("sensor_boxx") && err.contains("not defined"),
        "{err}"
    );

    let err = error(&with(
        r#"<link name="left_track">"#,
        r#"<link name="left_trak">"#,
    ));
    assert!(err.contains("bad.urdf"), "{err}");

    let err = RobotModel::from_urdf_str("<robot name='x'><link name=", "trunc.urdf")
        .unwrap_err()
        .to_string();
    assert!(err.starts_with("trunc.urdf: not a valid URDF"), "{err}");

    let r = tracked();
    let err = r.body_from("lidar_link").unwrap_err().to_string();
    assert!(
        err.contains("lidar_link") && err.contains("imu_link"),
        "{err}"
    );
    assert!(
        RobotModel::builtin("tank")
            .unwrap_err()
            .to_string()
            .contains("tracked-sensorbox")
    );
}

#[test]
fn malformed_drives_name_the_element_and_what_was_expected() {
    let cases: Vec<(String, &[&str])> = vec![
        (
            with("<kp>80000</kp>", "<kp>stiff</kp>"),
            &["<gazebo reference=\"left_track\">", "<kp>", "finite"],
        ),
        (
            with("<fdir1>1 0 0</fdir1>", ""),
            &["<gazebo reference=\"left_track\">", "missing <fdir1>"],
        ),
        (
            with(
                r#"<gazebo reference="right_track">"#,
                r#"<gazebo reference="elsewhere">"#,
            ),
            &["<gazebo reference=\"right_track\">", "missing"],
        ),
        (
            with(
                r#"<limit effort="80" velocity="15" acceleration="20"/>"#,
                r#"<limit effort="0" velocity="15"/>"#,
            ),
            &["left_sprocket_joint", "<limit effort>", "> 0"],
        ),
        (
            with(
                r#"<joint name="left_sprocket_joint" type="continuous">"#,
                r#"<joint name="left_sprocket_joint" type="prismatic">"#,
            ),
            &["left_sprocket_joint", "Prismatic", "not supported"],
        ),
        (
            with(
                "<tracks_separation>0.6</tracks_separation>",
                "<tracks_separation>0.7</tracks_separation>",
            ),
            &["TrackedVehicle", "<tracks_separation>", "0.6000"],
        ),
        (
            with(
                r#"<plugin filename="gz-sim-tracked-vehicle-system" name="gz::sim::systems::TrackedVehicle">"#,
                r#"<plugin filename="x" name="something_else">"#,
            ),
            &["<plugin>", "missing", "TrackedVehicle", "MecanumDrive"],
        ),
        (
            with(
                r#"<geometry><cylinder radius="0.1" length="0.2"/></geometry>"#,
                r#"<geometry><mesh filename="sprocket.stl"/></geometry>"#,
            ),
            &["left_sprocket", "mesh", "not supported"],
        ),
        (
            with(
                r#"<inertia ixx="0.0175" ixy="0" ixz="0" iyy="0.015" iyz="0" izz="0.0175"/>"#,
                r#"<inertia ixx="0.0175" ixy="0" ixz="0" iyy="0.335" iyz="0" izz="0.0175"/>"#,
            ),
            &["left_sprocket", "not a physical inertia tensor", "triangle"],
        ),
        (
            with(
                "<mechanicalReduction>40</mechanicalReduction>",
                "<mechanicalReduction>-4</mechanicalReduction>",
            ),
            &["left_sprocket_transmission", "<mechanicalReduction>", "> 0"],
        ),
        (
            with_rover(
                "<wheel_radius>0.0508</wheel_radius>",
                "<wheel_radius>0.06</wheel_radius>",
            ),
            &["MecanumDrive", "<wheel_radius>", "0.0508"],
        ),
        (
            with_rover(
                "<back_left_joint>rear_left_wheel_joint</back_left_joint>",
                "<back_left_joint>camera_mast_joint</back_left_joint>",
            ),
            &["camera_mast_joint", "continuous"],
        ),
        (
            with_rover("<fdir1>1 1 0</fdir1>", "<fdir1>0 0 0</fdir1>"),
            &["front_right_wheel", "<fdir1>", "not all zero"],
        ),
    ];
    for (text, needles) in cases {
        let err = error(&text);
        assert!(err.starts_with("bad.urdf:"), "{err}");
        for n in needles {
            assert!(err.contains(n), "`{n}` not in: {err}");
        }
    }
}

#[test]
fn bad_numbers_name_file_line_link_and_attribute() {
    // `<mass value="heavy"/>` of base_link (line 41, the attribute at column 13).
    let err = error(&with(
        r#"<mass value="120.0"/>"#,
        r#"<mass value="heavy"/>"#,
    ));
    assert!(
        err.starts_with("bad.urdf:41:13: <link name=\"base_link\">: <inertial><mass value>:")
            && err.contains("heavy")
            && err.contains("kg"),
        "{err}"
    );
    let err = error(&with(r#"<mass value="120.0"/>"#, "<mass/>"));
    assert!(
        err.starts_with("bad.urdf:41:7: <link name=\"base_link\">: <inertial><mass>: missing")
            && err.contains("value"),
        "{err}"
    );
    // A word among a vector's numbers (urdf-rs would skip it).
    let err = error(&with(
        r#"<origin xyz="-0.04 0.02 -0.03""#,
        r#"<origin xyz="-0.04 oops 0.02 -0.03""#,
    ));
    assert!(
        err.starts_with("bad.urdf:224:13: <joint name=\"imu_joint\">: <origin xyz>:")
            && err.contains("3 finite numbers"),
        "{err}"
    );
    let err = error(&with(r#"<mass value="120.0"/>"#, r#"<mass value="1e30"/>"#));
    assert!(
        err.starts_with("bad.urdf:38:")
            && err.contains("base_link")
            && err.contains("MAX_LINK_MASS_KG"),
        "{err}"
    );
    let err = error(&with(
        r#"<inertia ixx="4.9" ixy="0" ixz="0" iyy="10.4" iyz="0" izz="12.1"/>"#,
        r#"<inertia ixx="4.9e6" ixy="0" ixz="0" iyy="10.4e6" iyz="0" izz="12.1e6"/>"#,
    ));
    assert!(err.contains("MAX_GYRATION_RADIUS_M"), "{err}");
    let err = error(&with(
        r#"<joint name="imu_joint" type="fixed">"#,
        r#"<joint name="imu_joint" type="welded">"#,
    ));
    assert!(
        err.starts_with("bad.urdf:221:3: <joint name=\"imu_joint\">: attribute type")
            && err.contains("\"welded\""),
        "{err}"
    );
}

#[test]
fn other_roots_truncation_and_deep_nesting_are_named() {
    let err = error("<?xml version=\"1.0\"?>\n<sdf version=\"1.9\"><model name=\"m\"/></sdf>");
    assert!(
        err.starts_with("bad.urdf:2:1: <sdf>:") && err.contains("SDF") && err.contains("URDF"),
        "{err}"
    );
    let full = BUILTIN_MODELS[0].2;
    for cut in [full.len() / 3, full.len() / 2, full.len() - 10] {
        let mut at = cut;
        while !full.is_char_boundary(at) {
            at -= 1;
        }
        let err = error(&full[..at]);
        assert!(
            err.starts_with("bad.urdf: not a valid URDF") && err.contains("truncated"),
            "{err}"
        );
    }
    let deep = format!(
        "<robot name=\"r\">{}{}</robot>",
        "<a>".repeat(100_000),
        "</a>".repeat(100_000)
    );
    let err = error(&deep);
    assert!(err.contains("MAX_URDF_DEPTH"), "{err}");
}
