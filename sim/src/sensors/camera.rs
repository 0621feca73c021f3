//! Rendered cameras: RGB-D (D435-like), rectified stereo pairs (ZED2i-like) and a
//! high-resolution tag camera (ZED X mini-like).
//!
//! Each camera runs free on its own [`FrameClock`] (random start offset within a period,
//! per-frame period jitter); stamps are exposure-centre times. Per frame the camera
//! renders the truth at the stamp, then, like its sensor: rolling-shutter rows
//! ([`rolling_shutter`]), motion blur over the exposure time ([`motion_blur`]), the
//! exposure's gain and residual vignetting ([`crate::render::exposure`]: an auto-exposure
//! loop with a time constant unless the camera sets `exposure_ms`), shot and read noise
//! at the analog gain, sRGB. Per frame it publishes, RealSense/ZED style:
//!
//! | camera | topics |
//! |---|---|
//! | mono or RGB-D | `/<name>/color/image_raw` (`rgb8`), `/<name>/color/camera_info` |
//! | RGB-D depth | `/<name>/aligned_depth_to_color/image_raw` (`16UC1`, mm, 0 = none) |
//! | stereo pair | `/<name>/left/image_rect_color`, `/<name>/right/image_rect_color` and their `camera_info` |
//!
//! Depth is rendered from the colour camera's own rays (aligned by construction, from the
//! sharp render: the D435's depth imagers are global shutter with short exposures) and
//! passed through the D435 error model ([`StereoDepthNoise`]): disparity noise giving
//! `RMS(z) = z²·subpixel/(f·b)`, holes at depth edges, range limits, millimetre steps;
//! in daylight (`[sensors.stereo_depth] lighting = "sunlight"`) also holes where the
//! surface has no texture of its own ([`crate::render::depth_light`]).
//! Colour gets shot and read noise ([`ImageNoise`]) before sRGB encoding. Random streams:
//! `sensors.camera.<name>.clock` (timing) and `sensors.camera.<name>.noise` (pixels), so
//! image noise never shifts a stamp.

use super::{SensorContext, SensorModel, latency_from_ms, mount, require_rate};
use crate::params::{
    CameraExposureParams, CameraParams, DepthLighting, ParamError, RenderParams, StereoDepthParams,
    require_in, require_positive,
};
use crate::render::blur::{CameraMotion, motion_blur, rolling_shutter};
use crate::render::camera::{
    CameraProfile, CameraSpec, DepthScratch, FrameClock, ImageNoise, Intrinsics, RayTable,
    StereoDepthNoise,
};
use crate::render::depth_light::{SnrScratch, SunlightStereo};
use crate::render::exposure::{
    AutoExposure, Exposure, ExposureLimits, apply_gain, noise_at_gain, vignetting,
};
use crate::render::shade::{Frame, Renderer};
use crate::rng;
use crate::truth::TruthSample;
use nalgebra::Isometry3;
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;
use vinebench_msgs::{FrameId, ImageEncoding, ImageMsg, Message, Nanos, TimedMessage};

/// Default frame-period jitter, ms.
pub const DEFAULT_JITTER_MS: f64 = 0.5;
/// Default delivery latency, ms.
pub const DEFAULT_LATENCY_MS: f64 = 30.0;
/// Default farthest range of a colour pixel, m.
pub const DEFAULT_MAX_RANGE_M: f64 = 200.0;

/// Checks `[sensors.stereo_depth]` and `[sensors.camera_exposure]`, naming the key.
pub fn check_light(
    depth: &StereoDepthParams,
    exposure: &CameraExposureParams,
) -> Result<(), ParamError> {
    let d = |k: &str| format!("sensors.stereo_depth.{k}");
    require_in(&d("ambient_w_m2"), depth.ambient_w_m2, 0.0, 1e5)?;
    require_in(&d("projector_power_mw"), depth.projector_power_mw, 0.0, 1e5)?;
    for (k, fov) in depth.projector_fov_deg.iter().enumerate() {
        require_in(
            &format!("{}[{k}]", d("projector_fov_deg")),
            *fov,
            1.0,
            179.0,
        )?;
    }
    require_in(&d("dot_contrast"), depth.dot_contrast, 0.0, 100.0)?;
    if depth.window_px.is_multiple_of(2) || depth.window_px > 31 {
        return Err(ParamError::new(
            d("window_px"),
            "an odd window edge in 1..=31 px",
            depth.window_px,
        ));
    }
    require_in(&d("ae_level"), depth.ae_level, 1e-3, 1.0)?;
    require_positive(&d("snr_threshold"), depth.snr_threshold)?;
    require_in(&d("snr_softness"), depth.snr_softness, 1e-3, 10.0)?;
    require_positive(&d("snr_reference"), depth.snr_reference)?;
    let e = |k: &str| format!("sensors.camera_exposure.{k}");
    require_in(&e("target_level"), exposure.target_level, 1e-3, 1.0)?;
    require_in(&e("time_constant_s"), exposure.time_constant_s, 1e-3, 1e3)?;
    require_in(
        &e("reference_exposure_ms"),
        exposure.reference_exposure_ms,
        1e-4,
        1e4,
    )?;
    require_in(&e("min_exposure_ms"), exposure.min_exposure_ms, 1e-4, 1e4)?;
    require_in(
        &e("max_exposure_ms"),
        exposure.max_exposure_ms,
        exposure.min_exposure_ms,
        1e4,
    )?;
    require_in(&e("max_gain"), exposure.max_gain, 1.0, 1e4)?;
    require_in(&e("vignetting"), exposure.vignetting, 0.0, 1.0)?;
    Ok(())
}

/// One eye of a camera: where it is and what it publishes.
#[derive(Debug)]
struct Eye {
    body_from_optical: Isometry3<f64>,
    frame_id: FrameId,
    image_topic: Arc<str>,
    info_topic: Arc<str>,
    /// `-fx·baseline` in the CameraInfo P matrix of a right eye.
    right_baseline_m: f64,
}

/// A rendered camera (see the module docs).
#[derive(Debug)]
pub struct Camera {
    name: String,
    renderer: Arc<Renderer>,
    intrinsics: Intrinsics,
    rays: RayTable,
    pixel_angle_rad: f32,
    max_range_m: f32,
    eyes: Vec<Eye>,
    depth: Option<(StereoDepthNoise, Arc<str>)>,
    noise: ImageNoise,
    clock: FrameClock,
    clock_rng: ChaCha8Rng,
    noise_rng: ChaCha8Rng,
    latency: Nanos,
    frame: Frame,
    /// Manual exposure time for motion blur, s (0: sharp images); unused with `ae`.
    exposure_s: f64,
    /// The auto-exposure loop (`None`: manual exposure at the render's brightness).
    ae: Option<AutoExposure>,
    /// Residual vignetting factor per pixel (empty: none).
    vignette: Vec<f32>,
    /// The daylight stereo model of the depth image (`None`: indoor).
    sunlight: Option<SunlightStereo>,
    snr: Vec<f32>,
    snr_scratch: SnrScratch,
    /// Rolling-shutter frame readout time, s (0: global shutter).
    readout_s: f64,
    blur_scratch: Vec<[f32; 4]>,
    depth_scratch: DepthScratch,
    depth_mm: Vec<u16>,
}

impl Camera {
    /// Builds camera `index` of `[[sensors.cameras]]`, with the scenario's
    /// `[sensors.stereo_depth]` and `[sensors.camera_exposure]`.
    pub fn new(
        p: &CameraParams,
        index: usize,
        render: &RenderParams,
        light: (&StereoDepthParams, &CameraExposureParams),
        ctx: &SensorContext,
        renderer: Arc<Renderer>,
    ) -> Result<Camera, ParamError> {
        let (stereo_depth, exposure) = light;
        let path = format!("sensors.cameras[{index}]");
        if p.name.is_empty()
            || !p
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_')
        {
            return Err(ParamError::new(
                format!("{path}.name"),
                "a non-empty name of letters, digits and `_` (it becomes the topic prefix)",
                format!("`{}`", p.name),
            ));
        }
        let mut spec: CameraSpec = p.profile.spec();
        if p.width.is_some() || p.height.is_some() {
            let w = p.width.unwrap_or(spec.intrinsics.width);
            let h = p.height.unwrap_or(spec.intrinsics.height);
            if !(16..=8192).contains(&w) || !(16..=8192).contains(&h) {
                return Err(ParamError::new(
                    format!("{path}.width"),
                    "width and height in 16..=8192 px",
                    format!("{w}×{h}"),
                ));
            }
            spec = CameraSpec::of_profile(p.profile, w, h).map_err(|expected| {
                ParamError::new(format!("{path}.width"), expected, format!("{w}×{h}"))
            })?;
        }
        let rate_hz = require_rate(
            &format!("{path}.rate_hz"),
            p.rate_hz.unwrap_or(spec.rate_hz),
        )?;
        let jitter_ms = p.jitter_ms.unwrap_or(DEFAULT_JITTER_MS);
        crate::params::require_in(
            &format!("{path}.jitter_ms"),
            jitter_ms,
            0.0,
            1e3 / rate_hz / 4.0,
        )?;
        let latency_ms = p.latency_ms.unwrap_or(DEFAULT_LATENCY_MS);
        let latency = latency_from_ms(&format!("{path}.latency_ms"), latency_ms, rate_hz)?;
        let pixels = f64::from(spec.intrinsics.width) * f64::from(spec.intrinsics.height);
        let in_flight = rate_hz * latency_ms * 1e-3 * pixels;
        if in_flight > super::MAX_IN_FLIGHT_PIXELS {
            return Err(ParamError::new(
                format!("{path}.latency_ms"),
                format!(
                    "a latency keeping at most {:e} pixels of images in flight \
                     (MAX_IN_FLIGHT_PIXELS: rate_hz · latency · width · height), i.e. at most {} \
                     ms at {rate_hz} Hz and {}×{} px",
                    super::MAX_IN_FLIGHT_PIXELS,
                    super::MAX_IN_FLIGHT_PIXELS / (rate_hz * pixels) * 1e3,
                    spec.intrinsics.width,
                    spec.intrinsics.height
                ),
                latency_ms,
            ));
        }
        let exposure_ms = p.exposure_ms.unwrap_or(0.0);
        crate::params::require_in(
            &format!("{path}.exposure_ms"),
            exposure_ms,
            0.0,
            1e3 / rate_hz,
        )?;
        let ae = (exposure.auto && p.exposure_ms.is_none()).then(|| {
            AutoExposure::new(ExposureLimits {
                target_level: exposure.target_level,
                time_constant_s: exposure.time_constant_s,
                reference_s: exposure.reference_exposure_ms * 1e-3,
                min_s: exposure.min_exposure_ms.min(1e3 / rate_hz) * 1e-3,
                max_s: exposure.max_exposure_ms.min(1e3 / rate_hz) * 1e-3,
                max_gain: exposure.max_gain,
            })
        });
        let readout_ms = p.readout_ms.unwrap_or(p.profile.readout_ms());
        crate::params::require_in(
            &format!("{path}.readout_ms"),
            readout_ms,
            0.0,
            1e3 / rate_hz,
        )?;
        let max_range_m = p.max_range_m.unwrap_or(DEFAULT_MAX_RANGE_M);
        crate::params::require_in(&format!("{path}.max_range_m"), max_range_m, 0.1, 1e5)?;
        let sensor = format!("cameras[{index}]");
        let topic = |s: &str| -> Arc<str> { Arc::from(format!("/{}/{s}", p.name)) };
        let mut eyes = Vec::with_capacity(2);
        match &p.right_frame {
            None => eyes.push(Eye {
                body_from_optical: mount(ctx, &sensor, &p.frame)?,
                frame_id: FrameId::new(&p.frame),
                image_topic: topic("color/image_raw"),
                info_topic: topic("color/camera_info"),
                right_baseline_m: 0.0,
            }),
            Some(right) => {
                let left = mount(ctx, &sensor, &p.frame)?;
                let right_pose = mount(ctx, &sensor, right).map_err(|mut e| {
                    e.path = format!("{path}.right_frame");
                    e
                })?;
                let baseline = (left.inverse() * right_pose).translation.vector.x;
                eyes.push(Eye {
                    body_from_optical: left,
                    frame_id: FrameId::new(&p.frame),
                    image_topic: topic("left/image_rect_color"),
                    info_topic: topic("left/camera_info"),
                    right_baseline_m: 0.0,
                });
                eyes.push(Eye {
                    body_from_optical: right_pose,
                    frame_id: FrameId::new(right),
                    image_topic: topic("right/image_rect_color"),
                    info_topic: topic("right/camera_info"),
                    right_baseline_m: baseline,
                });
            }
        }
        let wants_depth = p
            .depth
            .unwrap_or(p.profile == CameraProfile::D435Depth && p.right_frame.is_none());
        let sunlight = (wants_depth && stereo_depth.lighting == DepthLighting::Sunlight)
            .then(|| SunlightStereo::from_params(stereo_depth, render));
        let depth = match (wants_depth, spec.stereo) {
            (false, _) => None,
            (true, Some(st)) => Some((
                StereoDepthNoise::new(&spec.intrinsics, &st),
                topic("aligned_depth_to_color/image_raw"),
            )),
            (true, None) => {
                return Err(ParamError::new(
                    format!("{path}.depth"),
                    "false for a camera without a depth unit (profile d435_color)",
                    "true",
                ));
            }
        };
        let intrinsics = spec.intrinsics;
        let rays = intrinsics.pixel_rays();
        let vignette = if exposure.vignetting > 0.0 {
            vignetting(&rays, exposure.vignetting)
        } else {
            Vec::new()
        };
        let mut clock_rng =
            rng::stream(ctx.master_seed, &format!("sensors.camera.{}.clock", p.name));
        let clock =
            FrameClock::from_rate_hz(ctx.start, rate_hz, jitter_ms * 1e6, 0.0, &mut clock_rng);
        let frame = Frame::new(intrinsics.width, intrinsics.height);
        let n = intrinsics.pixel_count();
        Ok(Camera {
            name: p.name.clone(),
            renderer,
            pixel_angle_rad: (1.0 / intrinsics.fx) as f32,
            max_range_m: max_range_m as f32,
            intrinsics,
            rays,
            eyes,
            depth,
            noise: ImageNoise {
                read_noise: render.read_noise as f32,
                shot_gain: render.shot_gain as f32,
            },
            clock,
            clock_rng,
            noise_rng: rng::stream(ctx.master_seed, &format!("sensors.camera.{}.noise", p.name)),
            latency,
            frame,
            exposure_s: exposure_ms * 1e-3,
            ae,
            vignette,
            snr: vec![0.0; if sunlight.is_some() { n } else { 0 }],
            sunlight,
            snr_scratch: SnrScratch::default(),
            readout_s: readout_ms * 1e-3,
            blur_scratch: Vec::new(),
            depth_scratch: DepthScratch::new(),
            depth_mm: vec![0; if wants_depth { n } else { 0 }],
        })
    }

    /// The camera's name.
    pub fn camera_name(&self) -> &str {
        &self.name
    }

    /// The calibration of every eye.
    pub fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }
}

impl SensorModel for Camera {
    fn name(&self) -> &'static str {
        "camera"
    }

    fn next_time(&self) -> Nanos {
        self.clock.peek()
    }

    fn sample(&mut self, truth: &TruthSample, out: &mut Vec<TimedMessage>) {
        let stamp = self.clock.next(&mut self.clock_rng);
        let arrival = stamp + self.latency;
        let t_s = stamp.as_secs_f64();
        let (w, h) = (self.intrinsics.width, self.intrinsics.height);
        // One exposure for every eye of the frame (a stereo pair's sensors share it).
        let mut exposure: Option<Exposure> = None;
        for (k, eye) in self.eyes.iter().enumerate() {
            let world_from_optical = truth.world_from_body * eye.body_from_optical;
            self.renderer.render(
                &self.rays,
                &world_from_optical,
                self.pixel_angle_rad,
                self.max_range_m,
                &mut self.frame,
            );
            if k == 0
                && self.depth.is_some()
                && let Some(model) = &self.sunlight
            {
                // The depth imagers' view: sharp (global shutter, short exposure).
                model.snr(self.frame.view(), &mut self.snr, &mut self.snr_scratch);
            }
            let e = match &mut self.ae {
                Some(ae) => {
                    let frame = &self.frame;
                    let e = *exposure.get_or_insert_with(|| ae.choose(t_s, frame));
                    if k == 0 {
                        ae.metered(t_s, e, frame);
                    }
                    e
                }
                None => Exposure {
                    time_s: self.exposure_s,
                    analog_gain: 1.0,
                    gain: 1.0,
                },
            };
            if e.time_s > 0.0 || self.readout_s > 0.0 {
                let k = truth.at_mount(&eye.body_from_optical);
                let motion = CameraMotion {
                    linear_mps: k.world_from_sensor.rotation.inverse() * k.velocity_in_world,
                    angular_radps: k.angular_velocity_in_sensor,
                };
                // Each row at its own time, then each pixel smeared over its exposure.
                rolling_shutter(
                    &mut self.frame,
                    &mut self.blur_scratch,
                    &self.rays,
                    self.intrinsics.fx,
                    self.intrinsics.fy,
                    &motion,
                    self.readout_s,
                );
                motion_blur(
                    &mut self.frame,
                    &mut self.blur_scratch,
                    &self.rays,
                    self.intrinsics.fx,
                    self.intrinsics.fy,
                    &motion,
                    e.time_s,
                );
            }
            if e.gain != 1.0 || !self.vignette.is_empty() {
                apply_gain(&mut self.frame, e.gain, &self.vignette);
            }
            let mut rgb = vec![0u8; self.frame.linear.len()];
            noise_at_gain(&self.noise, e.analog_gain).apply_encode_srgb(
                &self.frame.linear,
                &mut rgb,
                &mut self.noise_rng,
            );
            out.push(TimedMessage {
                arrival,
                msg: Message::Image(ImageMsg {
                    stamp,
                    topic: eye.image_topic.clone(),
                    frame_id: eye.frame_id.clone(),
                    width: w,
                    height: h,
                    encoding: ImageEncoding::Rgb8,
                    data: Arc::from(rgb),
                }),
            });
            out.push(TimedMessage {
                arrival,
                msg: Message::CameraInfo(self.intrinsics.camera_info_msg(
                    stamp,
                    eye.info_topic.clone(),
                    eye.frame_id.clone(),
                    eye.right_baseline_m,
                )),
            });
            if k == 0
                && let Some((model, topic)) = &self.depth
            {
                model.apply_in_light(
                    w,
                    h,
                    &self.frame.depth_m,
                    self.sunlight.as_ref().map(|m| (m, &self.snr[..])),
                    &mut self.depth_mm,
                    &mut self.depth_scratch,
                    &mut self.noise_rng,
                );
                let mut bytes = vec![0u8; 2 * self.depth_mm.len()];
                for (b, d) in bytes.chunks_exact_mut(2).zip(&self.depth_mm) {
                    b.copy_from_slice(&d.to_le_bytes());
                }
                out.push(TimedMessage {
                    arrival,
                    msg: Message::Image(ImageMsg {
                        stamp,
                        topic: topic.clone(),
                        frame_id: eye.frame_id.clone(),
                        width: w,
                        height: h,
                        encoding: ImageEncoding::Depth16Mm,
                        data: Arc::from(bytes),
                    }),
                });
            }
        }
    }
}
