//! EIF prediction throughput on deterministic synthetic IMU data.
//!
//! - `ins_predict/clone_active`: one [`InsCore::predict`] per IMU sample (nominal
//!   propagation + block-structured covariance propagation with the 15-dim clone active).
//! - `eif_handle_imu`: the whole filter fed IMU messages through `Estimator::handle`
//!   (interpolation, output at 50 Hz; no corrections).
//!
//! Target: ≥ 1 000 000 predictions per second on one core (`cargo bench --bench eif`).

// criterion's `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{BatchSize, Criterion, Throughput, black_box, criterion_group, criterion_main};
use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3};
use vinebench_msgs::geodesy::{Geodetic, LocalEnu};
use vinebench_msgs::{
    FixStatus, FrameId, GnssFixMsg, ImuMsg, Message, Nanos, OdometryMsg, StaticTransforms,
};
use vinebench_onboard::estimator::ins::{InsCore, ProcessNoise};
use vinebench_onboard::estimator::{Eif, EifParams, Estimator};

const STEPS: usize = 10_000;
const DT: f64 = vinebench::bench::SYNTHETIC_IMU_DT_S;

fn samples(n: usize) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    vinebench::bench::synthetic_imu(n)
}

fn core_with_clone() -> InsCore {
    vinebench::bench::synthetic_core()
}

fn bench_predict(c: &mut Criterion) {
    let data = samples(STEPS);
    let noise = ProcessNoise::from_datasheet(0.01, 0.002, 60.0, 20.0);
    let mut group = c.benchmark_group("ins_predict");
    group.throughput(Throughput::Elements(STEPS as u64));
    group.bench_function("clone_active", |b| {
        b.iter_batched_ref(
            core_with_clone,
            |core| {
                for (f, w) in &data {
                    core.predict(black_box(DT), f, w, &noise);
                }
                black_box(core.nav.p);
            },
            BatchSize::SmallInput,
        )
    });
    group.finish();
}

fn transforms() -> StaticTransforms {
    let mut t = StaticTransforms::new("base_link");
    t.insert("imu_link", Isometry3::translation(0.26, 0.02, 0.77));
    t.insert("gnss_antenna", Isometry3::translation(0.22, 0.0, 1.12));
    t.insert("tracking_camera", Isometry3::translation(0.41, 0.0, 0.74));
    t
}

fn imu_msg(k: usize, f: Vector3<f64>, w: Vector3<f64>) -> Message {
    Message::Imu(ImuMsg {
        stamp: Nanos(k as i64 * 5_000_000),
        frame_id: FrameId::new("imu_link"),
        orientation: Some(UnitQuaternion::identity()),
        orientation_covariance: Matrix3::identity() * 1e-4,
        angular_velocity: w,
        angular_velocity_covariance: Matrix3::identity() * 1e-8,
        linear_acceleration: f,
        linear_acceleration_covariance: Matrix3::identity() * 1e-6,
    })
}

fn bench_handle(c: &mut Criterion) {
    let enu = LocalEnu::new(Geodetic {
        lat_deg: 40.4545,
        lon_deg: 17.9085,
        alt_m: 55.0,
    });
    let params = EifParams {
        use_imu_orientation: false,
        ..EifParams::default()
    };
    let mut eif = Eif::new(&params, transforms(), enu.clone()).expect("valid defaults");
    let data = samples(STEPS + 2);
    // Initialise (IMU with AHRS, fix at the same stamp) and start the tracking clone.
    eif.handle(&imu_msg(0, data[0].0, data[0].1));
    eif.handle(&Message::GnssFix(GnssFixMsg {
        stamp: Nanos(0),
        frame_id: FrameId::new("gnss_antenna"),
        status: FixStatus::RtkFixed,
        position: enu.geodetic_from_enu(&Vector3::new(1.0, 2.0, 1.5)),
        position_covariance: Matrix3::identity() * 1e-4,
    }));
    eif.handle(&imu_msg(1, data[1].0, data[1].1));
    eif.handle(&Message::TrackingOdom(OdometryMsg {
        stamp: Nanos(5_000_000),
        frame_id: FrameId::new("tracking_odom"),
        child_frame_id: FrameId::new("tracking_camera"),
        pose: Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), UnitQuaternion::identity()),
        pose_covariance: Matrix6::identity() * 1e-6,
        linear_velocity: Vector3::zeros(),
        angular_velocity: Vector3::zeros(),
        twist_covariance: Matrix6::identity() * 1e-6,
    }));
    assert!(eif.is_initialized());
    let msgs: Vec<Message> = (2..STEPS + 2)
        .map(|k| imu_msg(k, data[k].0, data[k].1))
        .collect();
    let mut group = c.benchmark_group("eif_handle_imu");
    group.throughput(Throughput::Elements(STEPS as u64));
    group.bench_function("clone_active", |b| {
        b.iter_batched_ref(
            || eif.clone(),
            |e| {
                for m in &msgs {
                    e.handle(m);
                }
            },
            BatchSize::SmallInput,
        )
    });
    group.finish();
}

criterion_group!(benches, bench_predict, bench_handle);
criterion_main!(benches);
