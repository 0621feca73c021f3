//! Rendered cameras in a real scenario: free-running stamps, topics, image sizes, depth
//! validity and bit-identical frames for the same seed.

// Test helpers panic on failure by design.
#![allow(clippy::unwrap_used)]

use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::path::Path;
use vinebench::runner::setup;
use vinebench::scenario::LoadedScenario;
use vinebench_msgs::{ImageEncoding, Message, Nanos, TimedMessage};

/// The camera messages of the first `seconds` of `file`, in production order.
/// Every sensor message of the first `seconds` of a scenario, in sampling order.
fn sensor_messages(sc: &LoadedScenario, seconds: f64) -> Vec<TimedMessage> {
    let mut built = setup(sc).unwrap_or_else(|e| panic!("{e}"));
    let end = sc.start + Nanos::from_secs_f64(seconds);
    let mut out = Vec::new();
    loop {
        let t = built.sensors.iter().map(|s| s.next_time()).min().unwrap();
        if t > end {
            break;
        }
        let truth = built.motion.advance_to(t);
        for s in built.sensors.iter_mut() {
            if s.next_time() == t {
                s.sample(&truth, &mut out);
            }
        }
    }
    out
}

fn camera_messages(file: &str, seconds: f64) -> Vec<TimedMessage> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(file);
    let sc = LoadedScenario::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut out = sensor_messages(&sc, seconds);
    out.retain(|m| matches!(m.msg, Message::Image(_) | Message::CameraInfo(_)));
    out
}

fn digest(msgs: &[TimedMessage]) -> String {
    let mut h = Sha256::new();
    for m in msgs {
        if let Message::Image(img) = &m.msg {
            h.update(img.topic.as_bytes());
            h.update(img.stamp.0.to_le_bytes());
            h.update(&img.data[..]);
        }
    }
    format!("{:x}", h.finalize())
}

#[test]
fn the_tracked_rig_streams_three_free_running_rgbd_cameras() {
    let msgs = camera_messages("camera-row.toml", 1.0);
    let mut stamps: BTreeMap<String, Vec<i64>> = BTreeMap::new();
    let mut valid_depth = Vec::new();
    for m in &msgs {
        match &m.msg {
            Message::Image(img) => {
                assert_eq!((img.width, img.height), (640, 480), "{}", img.topic);
                assert_eq!(
                    img.data.len(),
                    640 * 480 * img.encoding.bytes_per_pixel(),
                    "{}",
                    img.topic
                );
                assert!(m.arrival > img.stamp, "latency");
                stamps
                    .entry(img.topic.to_string())
                    .or_default()
                    .push(img.stamp.0);
                if img.encoding == ImageEncoding::Depth16Mm {
                    let n = img
                        .data
                        .chunks_exact(2)
                        .filter(|b| u16::from_le_bytes([b[0], b[1]]) > 0)
                        .count();
                    valid_depth.push(n as f64 / (640.0 * 480.0));
                }
            }
            Message::CameraInfo(info) => {
                assert_eq!((info.width, info.height), (640, 480));
                assert!(info.k[0] > 300.0 && info.k[0] < 500.0, "fx {}", info.k[0]);
            }
            _ => unreachable!(),
        }
    }
    let names = [
        "/camera_center/color/image_raw",
        "/camera_center/aligned_depth_to_color/image_raw",
        "/camera_left/color/image_raw",
        "/camera_left/aligned_depth_to_color/image_raw",
        "/camera_right/color/image_raw",
        "/camera_right/aligned_depth_to_color/image_raw",
    ];
    assert_eq!(
        stamps.keys().cloned().collect::<Vec<_>>().len(),
        names.len()
    );
    for n in names {
        let s = &stamps[n];
        // 15 Hz for one second: 15 or 16 frames depending on the start offset.
        assert!((15..=16).contains(&s.len()), "{n}: {} frames", s.len());
        for w in s.windows(2) {
            let dt = (w[1] - w[0]) as f64 * 1e-9;
            assert!((dt - 1.0 / 15.0).abs() < 0.005, "{n}: period {dt} s");
        }
    }
    // Depth and colour of one camera share stamps; the three cameras do not.
    assert_eq!(
        stamps["/camera_center/color/image_raw"],
        stamps["/camera_center/aligned_depth_to_color/image_raw"]
    );
    let first = |n: &str| stamps[n][0];
    let phases = [
        first("/camera_center/color/image_raw"),
        first("/camera_left/color/image_raw"),
        first("/camera_right/color/image_raw"),
    ];
    assert!(
        phases[0] != phases[1] && phases[1] != phases[2] && phases[0] != phases[2],
        "cameras share a start phase: {phases:?}"
    );
    // The cameras see soil and vines within the D435's range in most pixels.
    let mean = valid_depth.iter().sum::<f64>() / valid_depth.len() as f64;
    assert!(mean > 0.4, "valid depth fraction {mean}");
}

#[test]
fn the_same_seed_gives_bit_identical_frames() {
    let a = camera_messages("camera-row.toml", 0.3);
    let b = camera_messages("camera-row.toml", 0.3);
    assert!(!a.is_empty());
    assert_eq!(digest(&a), digest(&b));
}

#[test]
fn the_rover_rig_streams_stereo_pairs_and_a_tag_camera() {
    let msgs = camera_messages("rover-occluder.toml", 0.5);
    let mut count: BTreeMap<String, (usize, u32, u32)> = BTreeMap::new();
    let mut right_tx = None;
    for m in &msgs {
        match &m.msg {
            Message::Image(img) => {
                let e = count.entry(img.topic.to_string()).or_default();
                *e = (e.0 + 1, img.width, img.height);
            }
            Message::CameraInfo(info) if &*info.topic == "/front/right/camera_info" => {
                right_tx = Some(info.p[3] / info.p[0]);
            }
            _ => {}
        }
    }
    for (topic, w, h) in [
        ("/front/left/image_rect_color", 752, 480),
        ("/front/right/image_rect_color", 752, 480),
        ("/rear/left/image_rect_color", 752, 480),
        ("/rear/right/image_rect_color", 752, 480),
        ("/side/color/image_raw", 1920, 1080),
    ] {
        let (n, gw, gh) = count.get(topic).copied().unwrap_or_default();
        assert!(n >= 2, "{topic}: {n} images");
        assert_eq!((gw, gh), (w, h), "{topic}");
    }
    // The right camera's P carries -baseline (ZED2i: 12 cm) from the URDF frames.
    let tx = right_tx.expect("right camera info");
    assert!((tx + 0.12).abs() < 1e-6, "Tx/fx = {tx}");
}

/// `scenarios/camera-row.toml` with its centre camera only (the text before the left
/// camera's table).
fn camera_row_centre_only() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/camera-row.toml");
    let base = std::fs::read_to_string(&path).unwrap();
    let cut = base
        .find("[[sensors.cameras]]\nname = \"camera_left\"")
        .unwrap();
    base[..cut].to_string()
}

#[test]
fn an_exposure_blurs_colour_images_and_is_checked_against_the_frame_period() {
    // Only the centre camera, and the robot drives off after half a second, to keep the
    // test short.
    let one = format!(
        "{}\n[motion]\nstill_before_s = 0.5\n",
        camera_row_centre_only()
    );
    let with = |ms: f64| {
        let toml = one.replace(
            "name = \"camera_center\"",
            &format!("name = \"camera_center\"\nexposure_ms = {ms}"),
        );
        LoadedScenario::from_str(&toml, "camera-row-exposure").unwrap()
    };
    // 15 Hz: an exposure longer than the 66.7 ms period is refused, naming the key.
    let err = setup(&with(80.0))
        .err()
        .expect("an 80 ms exposure at 15 Hz");
    assert!(
        err.to_string().contains("sensors.cameras[0].exposure_ms"),
        "{err}"
    );
    // A moving robot: a 30 ms exposure changes the colour images, not their stamps, and
    // leaves the depth images alone.
    let frames = |sc: &LoadedScenario| {
        let end = sc.start + Nanos::from_secs_f64(2.5);
        sensor_messages(sc, 2.5)
            .into_iter()
            .filter_map(|m| match m.msg {
                Message::Image(img) if img.stamp > end - Nanos::from_secs_f64(0.2) => Some(img),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    let (sharp, blurred) = (frames(&with(0.0)), frames(&with(30.0)));
    assert_eq!(sharp.len(), blurred.len());
    assert!(!sharp.is_empty());
    for (a, b) in sharp.iter().zip(&blurred) {
        assert_eq!((a.stamp, &a.topic), (b.stamp, &b.topic));
        if a.encoding == ImageEncoding::Depth16Mm {
            assert_eq!(a.data, b.data, "depth is not blurred");
        } else {
            assert_ne!(a.data, b.data, "{} at {} is not blurred", a.topic, a.stamp);
        }
    }
}

/// The auto-exposure holds the colour images' mean linear level near its target
/// (`[sensors.camera_exposure] target_level`, 0.18) however bright the render is, while
/// a fixed exposure follows the render: the tracked rig's centre camera with the render
/// two stops too bright.
#[test]
fn auto_exposure_holds_the_target_level_where_a_fixed_exposure_follows_the_scene() {
    use vinebench_sim::render::camera::srgb_u8_to_linear;
    let base = camera_row_centre_only();
    let mean_levels = |auto: bool| {
        let toml = format!(
            "{}\n[sensors.camera_exposure]\nauto = {auto}\n",
            base.replace("[render]\n", "[render]\nexposure = 4.0\n")
        );
        let sc = LoadedScenario::from_str(&toml, "camera-row-ae").unwrap();
        sensor_messages(&sc, 1.5)
            .into_iter()
            .filter_map(|m| match m.msg {
                Message::Image(img) if img.encoding == ImageEncoding::Rgb8 => Some(
                    img.data
                        .chunks_exact(3)
                        .map(|c| {
                            f64::from(
                                srgb_u8_to_linear(c[0])
                                    + srgb_u8_to_linear(c[1])
                                    + srgb_u8_to_linear(c[2]),
                            ) / 3.0
                        })
                        .sum::<f64>()
                        / (img.data.len() / 3) as f64,
                ),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    let (auto, fixed) = (mean_levels(true), mean_levels(false));
    assert!(auto.len() >= 15 && auto.len() == fixed.len());
    // Vignetting (a quarter of cos⁴ at the corners) takes a few per cent off the metered
    // level; sRGB quantisation and noise a little more either way.
    for (k, m) in auto.iter().enumerate() {
        assert!((0.14..0.2).contains(m), "frame {k}: mean level {m:.3}");
    }
    let fixed_mean = fixed.iter().sum::<f64>() / fixed.len() as f64;
    eprintln!("auto-exposed frames' mean levels {auto:.3?}; fixed exposure {fixed_mean:.3}");
    assert!(fixed_mean > 0.3, "two stops over: {fixed_mean:.3}");
}
