//! An optional [`RayCaster`] backend on Intel Embree 3 (feature `embree`).
//!
//! The scene is built two-level like [`TraceScene`]: one Embree scene per mesh (a single
//! triangle geometry, `float3` vertices and `uint3` indices) and a top scene of instance
//! geometries carrying each [`Instance`](super::Instance)'s 3×4 transform, attached under the instance's
//! index so Embree's instance ID is the index in [`TraceScene::instances`]. All scenes use
//! high build quality and the robust flag (conservative traversal and the watertight
//! Plücker triangle test), so rays through shared edges and vertices never slip through.
//!
//! Packets are traced with `rtcIntersect4/8/16` or with Embree's coherent ray-stream call,
//! see [`PacketMode`]; single rays with `rtcIntersect1`. All of them return bit-identical
//! hits. Debian's Embree 3.13 is built for SSE2 to AVX-512 and picks the best at run time;
//! on an AVX-512 CPU (Zen 4, one thread, a 640×480 view of the synthetic vegetation
//! scene) 16-wide packets ran about 10 Mrays/s, the coherent stream 8.5, 8-wide packets
//! 6–8.5, 4-wide 5 and single rays 3: [`PacketMode::Auto`] takes the widest native width.
//! The robust flag costs little there, while without it about 4 % of rays aimed exactly
//! at shared edges and vertices slipped through a mesh.
//!
//! Linking needs `libembree3.so` (Debian: `libembree-dev`, installed by
//! `scripts/install-embree.sh`); for an Embree elsewhere pass its library folder with
//! `RUSTFLAGS="-L /path/to/lib"`. Without the feature nothing here is compiled or linked.

// This module is the crate's only FFI boundary: it declares the few Embree 3 C functions
// and structures it calls and wraps them in a safe `RayCaster`. The workspace denies
// unsafe code everywhere else.
#![allow(unsafe_code)]

use std::ffi::{CStr, CString, c_char, c_void};
use std::fmt;
use std::sync::Mutex;
use std::sync::atomic::{AtomicIsize, Ordering};

use super::trace::{Hit, PACKET_SIZE, RayCaster, RayPacket};
use super::{Affine3, TraceScene};

/// Minimal hand-written bindings to Embree 3.13 (`embree3/rtcore.h`), only what this
/// module uses. Layouts follow the header for `RTC_MAX_INSTANCE_LEVEL_COUNT == 1` and
/// `RTC_MIN_WIDTH == 0`, which is how Embree 3 is built by default and by Debian.
mod sys {
    use std::ffi::{c_char, c_void};

    /// Opaque `RTCDeviceTy`.
    #[repr(C)]
    pub struct DeviceTy {
        _private: [u8; 0],
    }
    /// Opaque `RTCSceneTy`.
    #[repr(C)]
    pub struct SceneTy {
        _private: [u8; 0],
    }
    /// Opaque `RTCGeometryTy`.
    #[repr(C)]
    pub struct GeometryTy {
        _private: [u8; 0],
    }
    pub type RTCDevice = *mut DeviceTy;
    pub type RTCScene = *mut SceneTy;
    pub type RTCGeometry = *mut GeometryTy;

    pub const RTC_INVALID_GEOMETRY_ID: u32 = u32::MAX;

    // enum RTCError
    pub const RTC_ERROR_NONE: u32 = 0;
    // enum RTCDeviceProperty
    pub const RTC_DEVICE_PROPERTY_VERSION: u32 = 0;
    pub const RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED: u32 = 32;
    pub const RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED: u32 = 33;
    pub const RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED: u32 = 34;
    pub const RTC_DEVICE_PROPERTY_RAY_STREAM_SUPPORTED: u32 = 35;
    // enum RTCGeometryType
    pub const RTC_GEOMETRY_TYPE_TRIANGLE: u32 = 0;
    pub const RTC_GEOMETRY_TYPE_INSTANCE: u32 = 121;
    // enum RTCBufferType
    pub const RTC_BUFFER_TYPE_INDEX: u32 = 0;
    pub const RTC_BUFFER_TYPE_VERTEX: u32 = 1;
    // enum RTCFormat
    pub const RTC_FORMAT_UINT3: u32 = 0x5003;
    pub const RTC_FORMAT_FLOAT3: u32 = 0x9003;
    pub const RTC_FORMAT_FLOAT3X4_ROW_MAJOR: u32 = 0x9134;
    // enum RTCBuildQuality
    pub const RTC_BUILD_QUALITY_HIGH: u32 = 2;
    // enum RTCSceneFlags
    pub const RTC_SCENE_FLAG_NONE: u32 = 0;
    pub const RTC_SCENE_FLAG_ROBUST: u32 = 1 << 2;
    // enum RTCIntersectContextFlags
    pub const RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT: u32 = 0;
    pub const RTC_INTERSECT_CONTEXT_FLAG_COHERENT: u32 = 1;

    /// `struct RTCIntersectContext`.
    #[repr(C)]
    pub struct RTCIntersectContext {
        pub flags: u32,
        pub filter: Option<unsafe extern "C" fn(args: *const c_void)>,
        pub inst_id: [u32; 1],
    }

    impl RTCIntersectContext {
        /// What the header's inline `rtcInitIntersectContext` does, with `flags`.
        pub fn new(flags: u32) -> Self {
            RTCIntersectContext {
                flags,
                filter: None,
                inst_id: [RTC_INVALID_GEOMETRY_ID],
            }
        }
    }

    /// `struct RTCRayHit`: `RTCRay` then `RTCHit`, both 16-byte aligned.
    #[repr(C, align(16))]
    pub struct RTCRayHit {
        pub org_x: f32,
        pub org_y: f32,
        pub org_z: f32,
        pub tnear: f32,
        pub dir_x: f32,
        pub dir_y: f32,
        pub dir_z: f32,
        pub time: f32,
        pub tfar: f32,
        pub mask: u32,
        pub id: u32,
        pub flags: u32,
        pub ng_x: f32,
        pub ng_y: f32,
        pub ng_z: f32,
        pub u: f32,
        pub v: f32,
        pub prim_id: u32,
        pub geom_id: u32,
        pub inst_id: [u32; 1],
    }

    /// `struct RTCRayHit4/8/16` for `N` = 4, 8, 16: `RTCRayN` (12 lanes arrays) then
    /// `RTCHitN` (8 lane arrays). Every field is `4·N` bytes, so there is no padding and the
    /// hit part starts at `48·N` bytes as in C; 64-byte alignment covers all three widths.
    #[repr(C, align(64))]
    pub struct RTCRayHitN<const N: usize> {
        pub org_x: [f32; N],
        pub org_y: [f32; N],
        pub org_z: [f32; N],
        pub tnear: [f32; N],
        pub dir_x: [f32; N],
        pub dir_y: [f32; N],
        pub dir_z: [f32; N],
        pub time: [f32; N],
        pub tfar: [f32; N],
        pub mask: [u32; N],
        pub id: [u32; N],
        pub flags: [u32; N],
        pub ng_x: [f32; N],
        pub ng_y: [f32; N],
        pub ng_z: [f32; N],
        pub u: [f32; N],
        pub v: [f32; N],
        pub prim_id: [u32; N],
        pub geom_id: [u32; N],
        pub inst_id: [[u32; N]; 1],
    }

    impl<const N: usize> RTCRayHitN<N> {
        /// `N` rays from `origin` over `[tnear, tfar]` along `+z` (callers set the
        /// directions), hits cleared as Embree requires (`geomID` invalid).
        pub fn new(origin: [f32; 3], tnear: f32, tfar: f32) -> Self {
            RTCRayHitN {
                org_x: [origin[0]; N],
                org_y: [origin[1]; N],
                org_z: [origin[2]; N],
                tnear: [tnear; N],
                dir_x: [0.0; N],
                dir_y: [0.0; N],
                dir_z: [1.0; N],
                time: [0.0; N],
                tfar: [tfar; N],
                mask: [u32::MAX; N],
                id: [0; N],
                flags: [0; N],
                ng_x: [0.0; N],
                ng_y: [0.0; N],
                ng_z: [0.0; N],
                u: [0.0; N],
                v: [0.0; N],
                prim_id: [RTC_INVALID_GEOMETRY_ID; N],
                geom_id: [RTC_INVALID_GEOMETRY_ID; N],
                inst_id: [[RTC_INVALID_GEOMETRY_ID; N]],
            }
        }
    }

    /// The `valid` lane mask of `rtcIntersect4/8/16` (-1 valid, 0 not): Embree loads it with
    /// aligned vector loads, so it needs the packet's alignment too.
    #[repr(C, align(64))]
    pub struct ValidMask<const N: usize>(pub [i32; N]);

    /// `struct RTCRayHitNp`: pointers to structure-of-arrays ray and hit data.
    #[repr(C)]
    pub struct RTCRayHitNp {
        pub org_x: *mut f32,
        pub org_y: *mut f32,
        pub org_z: *mut f32,
        pub tnear: *mut f32,
        pub dir_x: *mut f32,
        pub dir_y: *mut f32,
        pub dir_z: *mut f32,
        pub time: *mut f32,
        pub tfar: *mut f32,
        pub mask: *mut u32,
        pub id: *mut u32,
        pub flags: *mut u32,
        pub ng_x: *mut f32,
        pub ng_y: *mut f32,
        pub ng_z: *mut f32,
        pub u: *mut f32,
        pub v: *mut f32,
        pub prim_id: *mut u32,
        pub geom_id: *mut u32,
        pub inst_id: [*mut u32; 1],
    }

    // Layout checks against the C header.
    const _: () = {
        assert!(size_of::<RTCIntersectContext>() == 24);
        assert!(std::mem::offset_of!(RTCIntersectContext, inst_id) == 16);
        assert!(size_of::<RTCRayHit>() == 80);
        assert!(std::mem::offset_of!(RTCRayHit, ng_x) == 48);
        assert!(std::mem::offset_of!(RTCRayHitN<4>, ng_x) == 192);
        assert!(size_of::<RTCRayHitN<4>>() == 320);
        assert!(std::mem::offset_of!(RTCRayHitN<8>, ng_x) == 384);
        assert!(size_of::<RTCRayHitN<8>>() == 640);
        assert!(std::mem::offset_of!(RTCRayHitN<16>, ng_x) == 768);
        assert!(std::mem::offset_of!(RTCRayHitN<16>, inst_id) == 1216);
        assert!(size_of::<RTCRayHitN<16>>() == 1280);
        assert!(size_of::<RTCRayHitNp>() == 20 * 8);
    };

    pub type RTCErrorFunction =
        unsafe extern "C" fn(user_ptr: *mut c_void, code: u32, message: *const c_char);
    pub type RTCMemoryMonitorFunction =
        unsafe extern "C" fn(user_ptr: *mut c_void, bytes: isize, post: bool) -> bool;
    /// `rtcIntersect4/8/16`, with the ray/hit packet passed untyped.
    pub type IntersectN = unsafe extern "C" fn(
        valid: *const i32,
        scene: RTCScene,
        context: *mut RTCIntersectContext,
        rayhit: *mut c_void,
    );

    #[link(name = "embree3")]
    unsafe extern "C" {
        pub fn rtcNewDevice(config: *const c_char) -> RTCDevice;
        pub fn rtcReleaseDevice(device: RTCDevice);
        pub fn rtcGetDeviceProperty(device: RTCDevice, prop: u32) -> isize;
        pub fn rtcGetDeviceError(device: RTCDevice) -> u32;
        pub fn rtcSetDeviceErrorFunction(
            device: RTCDevice,
            error: Option<RTCErrorFunction>,
            user_ptr: *mut c_void,
        );
        pub fn rtcSetDeviceMemoryMonitorFunction(
            device: RTCDevice,
            monitor: Option<RTCMemoryMonitorFunction>,
            user_ptr: *mut c_void,
        );

        pub fn rtcNewScene(device: RTCDevice) -> RTCScene;
        pub fn rtcReleaseScene(scene: RTCScene);
        pub fn rtcSetSceneFlags(scene: RTCScene, flags: u32);
        pub fn rtcSetSceneBuildQuality(scene: RTCScene, quality: u32);
        pub fn rtcAttachGeometryByID(scene: RTCScene, geometry: RTCGeometry, geom_id: u32);
        pub fn rtcCommitScene(scene: RTCScene);

        pub fn rtcNewGeometry(device: RTCDevice, kind: u32) -> RTCGeometry;
        pub fn rtcReleaseGeometry(geometry: RTCGeometry);
        pub fn rtcCommitGeometry(geometry: RTCGeometry);
        pub fn rtcSetGeometryBuildQuality(geometry: RTCGeometry, quality: u32);
        pub fn rtcSetNewGeometryBuffer(
            geometry: RTCGeometry,
            kind: u32,
            slot: u32,
            format: u32,
            byte_stride: usize,
            item_count: usize,
        ) -> *mut c_void;
        pub fn rtcSetGeometryInstancedScene(geometry: RTCGeometry, scene: RTCScene);
        pub fn rtcSetGeometryTransform(
            geometry: RTCGeometry,
            time_step: u32,
            format: u32,
            xfm: *const c_void,
        );

        pub fn rtcIntersect1(
            scene: RTCScene,
            context: *mut RTCIntersectContext,
            rayhit: *mut RTCRayHit,
        );
        pub fn rtcIntersect4(
            valid: *const i32,
            scene: RTCScene,
            context: *mut RTCIntersectContext,
            rayhit: *mut c_void,
        );
        pub fn rtcIntersect8(
            valid: *const i32,
            scene: RTCScene,
            context: *mut RTCIntersectContext,
            rayhit: *mut c_void,
        );
        pub fn rtcIntersect16(
            valid: *const i32,
            scene: RTCScene,
            context: *mut RTCIntersectContext,
            rayhit: *mut c_void,
        );
        pub fn rtcIntersectNp(
            scene: RTCScene,
            context: *mut RTCIntersectContext,
            rayhit: *const RTCRayHitNp,
            n: u32,
        );
    }
}

/// How [`EmbreeCaster::cast_packet`] hands a 64-ray packet to Embree.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PacketMode {
    /// The widest packet call Embree runs natively on this CPU (16 with AVX-512, 8 with
    /// AVX/AVX2, else 4).
    Auto,
    /// One `rtcIntersect1` per ray.
    Single,
    /// 16 calls of `rtcIntersect4`.
    Packet4,
    /// 8 calls of `rtcIntersect8`.
    Packet8,
    /// 4 calls of `rtcIntersect16`.
    Packet16,
    /// One `rtcIntersectNp` call over the whole packet as a coherent ray stream.
    Stream,
}

/// What [`EmbreeCaster::with_options`] builds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EmbreeOptions {
    /// Packet tracing strategy.
    pub packet_mode: PacketMode,
    /// Set `RTC_SCENE_FLAG_ROBUST` on all scenes (watertight; a little slower).
    pub robust: bool,
    /// Embree device configuration string (`rtcNewDevice`), e.g. `"max_isa=avx2"` or
    /// `"threads=1"`; empty for Embree's defaults.
    pub device_config: String,
}

impl Default for EmbreeOptions {
    fn default() -> Self {
        EmbreeOptions {
            packet_mode: PacketMode::Auto,
            robust: true,
            device_config: String::new(),
        }
    }
}

/// Why an [`EmbreeCaster`] could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EmbreeError {
    /// Embree reported an error (unsupported CPU, out of memory, invalid argument, ...).
    #[error("embree: {0}")]
    Embree(String),
    /// The scene cannot be handed to Embree as it is.
    #[error("embree: invalid scene: {0}")]
    InvalidScene(String),
}

/// Shared with Embree's callbacks through a user pointer; boxed so its address is stable.
#[derive(Default)]
struct DeviceState {
    /// Bytes Embree currently holds for this device.
    memory: AtomicIsize,
    /// The first error Embree reported through the error callback.
    first_error: Mutex<Option<String>>,
}

/// Embree's error callback: keeps the first message.
unsafe extern "C" fn on_error(user_ptr: *mut c_void, code: u32, message: *const c_char) {
    // SAFETY: `user_ptr` is the `DeviceState` box registered with the device; it outlives
    // the device (released in `EmbreeCaster::drop` before the box is dropped).
    let state = unsafe { &*(user_ptr as *const DeviceState) };
    let text = if message.is_null() {
        String::from("(no message)")
    } else {
        // SAFETY: Embree passes a NUL-terminated string valid for this call.
        unsafe { CStr::from_ptr(message) }
            .to_string_lossy()
            .into_owned()
    };
    if let Ok(mut first) = state.first_error.lock()
        && first.is_none()
    {
        *first = Some(format!("{text} (error code {code})"));
    }
}

/// Embree's memory monitor: keeps a running total of the device's bytes.
unsafe extern "C" fn on_memory(user_ptr: *mut c_void, bytes: isize, _post: bool) -> bool {
    // SAFETY: as in `on_error`.
    let state = unsafe { &*(user_ptr as *const DeviceState) };
    state.memory.fetch_add(bytes, Ordering::Relaxed);
    true
}

/// The Embree 3 backend: a two-level Embree scene mirroring a [`TraceScene`].
pub struct EmbreeCaster {
    device: sys::RTCDevice,
    /// The top scene of instances (null only while building).
    top: sys::RTCScene,
    /// One scene per mesh; null for meshes without triangles.
    meshes: Vec<sys::RTCScene>,
    /// Callback state; must outlive `device`.
    state: Box<DeviceState>,
    /// The resolved packet mode (never `Auto`).
    mode: PacketMode,
    /// Bytes of the vertex and index buffers Embree copied from the scene.
    geometry_bytes: usize,
    /// Native packet widths of the device: 4, 8, 16.
    native: [bool; 3],
}

// SAFETY: the handles are only used for intersection queries after all scenes were
// committed in the constructor; Embree documents committed scenes as safe to query from
// any number of threads concurrently, and nothing mutates them until `drop`, which has
// exclusive access. `DeviceState` is only touched through atomics and a mutex.
unsafe impl Send for EmbreeCaster {}
// SAFETY: see `Send`; `&self` methods only run read-only Embree queries.
unsafe impl Sync for EmbreeCaster {}

impl fmt::Debug for EmbreeCaster {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("EmbreeCaster")
            .field("meshes", &self.meshes.len())
            .field("mode", &self.mode)
            .field("native", &self.native)
            .finish_non_exhaustive()
    }
}

impl Drop for EmbreeCaster {
    fn drop(&mut self) {
        // SAFETY: each handle was created by this device and is released exactly once here;
        // the top scene (which references the mesh scenes through instances) goes first,
        // the device last. `state` is dropped after this body, so callbacks fired during
        // release still see it.
        unsafe {
            if !self.top.is_null() {
                sys::rtcReleaseScene(self.top);
            }
            for &scene in &self.meshes {
                if !scene.is_null() {
                    sys::rtcReleaseScene(scene);
                }
            }
            if !self.device.is_null() {
                sys::rtcReleaseDevice(self.device);
            }
        }
    }
}

impl EmbreeCaster {
    /// Builds the Embree scenes for `scene` with [`EmbreeOptions::default`].
    pub fn new(scene: &TraceScene) -> Result<EmbreeCaster, EmbreeError> {
        Self::with_options(scene, &EmbreeOptions::default())
    }

    /// Builds the Embree scenes for `scene`.
    ///
    /// Fails when Embree cannot start on this machine, when an instance names a missing
    /// mesh or has a singular transform, or when a triangle indexes past its positions.
    pub fn with_options(
        scene: &TraceScene,
        options: &EmbreeOptions,
    ) -> Result<EmbreeCaster, EmbreeError> {
        validate(scene)?;
        let config = CString::new(options.device_config.as_str())
            .map_err(|_| EmbreeError::InvalidScene("device config contains NUL".into()))?;
        // SAFETY: `config` is a valid NUL-terminated string for the duration of the call.
        let device = unsafe { sys::rtcNewDevice(config.as_ptr()) };
        if device.is_null() {
            // SAFETY: a null device queries the thread's global error code.
            let code = unsafe { sys::rtcGetDeviceError(std::ptr::null_mut()) };
            return Err(EmbreeError::Embree(format!(
                "rtcNewDevice failed (error code {code})"
            )));
        }
        let mut caster = EmbreeCaster {
            device,
            top: std::ptr::null_mut(),
            meshes: Vec::with_capacity(scene.meshes.len()),
            state: Box::default(),
            mode: options.packet_mode,
            geometry_bytes: 0,
            native: [false; 3],
        };
        let user_ptr = &*caster.state as *const DeviceState as *mut c_void;
        // SAFETY: `device` is valid; `user_ptr` points at the boxed state, which lives until
        // after the device is released (see `Drop`). The callbacks only read through it.
        unsafe {
            sys::rtcSetDeviceErrorFunction(device, Some(on_error), user_ptr);
            sys::rtcSetDeviceMemoryMonitorFunction(device, Some(on_memory), user_ptr);
        }
        caster.native = [
            sys::RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED,
            sys::RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED,
            sys::RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED,
        ]
        .map(|p| caster.device_property(p) != 0);
        if caster.mode == PacketMode::Auto {
            caster.mode = match caster.native {
                [_, _, true] => PacketMode::Packet16,
                [_, true, _] => PacketMode::Packet8,
                _ => PacketMode::Packet4,
            };
        }
        if caster.mode == PacketMode::Stream
            && caster.device_property(sys::RTC_DEVICE_PROPERTY_RAY_STREAM_SUPPORTED) == 0
        {
            return Err(EmbreeError::Embree(
                "this Embree build has no ray-stream support".into(),
            ));
        }
        let flags = if options.robust {
            sys::RTC_SCENE_FLAG_ROBUST
        } else {
            sys::RTC_SCENE_FLAG_NONE
        };

        for mesh in &scene.meshes {
            if mesh.indices.is_empty() {
                caster.meshes.push(std::ptr::null_mut());
                continue;
            }
            // SAFETY: `device` is valid; the returned scene is owned by `caster.meshes` and
            // released in `Drop` (pushed before anything can fail).
            let mesh_scene = unsafe { sys::rtcNewScene(device) };
            caster.check("rtcNewScene")?;
            caster.meshes.push(mesh_scene);
            // SAFETY: `mesh_scene` and `device` are valid handles. The new buffers are
            // allocated by Embree with exactly the item count and stride requested, so the
            // copies below write `positions.len()` resp. `indices.len()` items of 12 bytes
            // into memory Embree owns; `[f32; 3]` and `[u32; 3]` are 12 bytes with 4-byte
            // alignment, and Embree's buffers are at least 16-byte aligned. Every index is
            // below `positions.len()` (checked by `validate`). The geometry reference is
            // released after attaching, the scene keeps its own.
            unsafe {
                sys::rtcSetSceneFlags(mesh_scene, flags);
                sys::rtcSetSceneBuildQuality(mesh_scene, sys::RTC_BUILD_QUALITY_HIGH);
                let geom = sys::rtcNewGeometry(device, sys::RTC_GEOMETRY_TYPE_TRIANGLE);
                caster.check("rtcNewGeometry(TRIANGLE)")?;
                sys::rtcSetGeometryBuildQuality(geom, sys::RTC_BUILD_QUALITY_HIGH);
                let vertices = sys::rtcSetNewGeometryBuffer(
                    geom,
                    sys::RTC_BUFFER_TYPE_VERTEX,
                    0,
                    sys::RTC_FORMAT_FLOAT3,
                    12,
                    mesh.positions.len(),
                ) as *mut [f32; 3];
                let indices = sys::rtcSetNewGeometryBuffer(
                    geom,
                    sys::RTC_BUFFER_TYPE_INDEX,
                    0,
                    sys::RTC_FORMAT_UINT3,
                    12,
                    mesh.indices.len(),
                ) as *mut [u32; 3];
                if vertices.is_null() || indices.is_null() {
                    sys::rtcReleaseGeometry(geom);
                    caster.check("rtcSetNewGeometryBuffer")?;
                    return Err(EmbreeError::Embree(
                        "rtcSetNewGeometryBuffer returned null".into(),
                    ));
                }
                std::ptr::copy_nonoverlapping(
                    mesh.positions.as_ptr(),
                    vertices,
                    mesh.positions.len(),
                );
                std::ptr::copy_nonoverlapping(mesh.indices.as_ptr(), indices, mesh.indices.len());
                sys::rtcCommitGeometry(geom);
                sys::rtcAttachGeometryByID(mesh_scene, geom, 0);
                sys::rtcReleaseGeometry(geom);
                sys::rtcCommitScene(mesh_scene);
            }
            caster.check("building a mesh scene")?;
            caster.geometry_bytes += 12 * (mesh.positions.len() + mesh.indices.len());
        }

        // SAFETY: `device` is valid; the scene is owned by `caster.top`, released in `Drop`.
        caster.top = unsafe { sys::rtcNewScene(device) };
        caster.check("rtcNewScene")?;
        // SAFETY: `caster.top` is a valid scene of `device`.
        unsafe {
            sys::rtcSetSceneFlags(caster.top, flags);
            sys::rtcSetSceneBuildQuality(caster.top, sys::RTC_BUILD_QUALITY_HIGH);
        }
        for (index, instance) in scene.instances.iter().enumerate() {
            let mesh_scene = caster.meshes[instance.mesh as usize];
            if mesh_scene.is_null() {
                continue; // an empty mesh is never hit
            }
            let id = u32::try_from(index)
                .ok()
                .filter(|&id| id != sys::RTC_INVALID_GEOMETRY_ID)
                .ok_or_else(|| EmbreeError::InvalidScene("too many instances".into()))?;
            // SAFETY: `device`, `mesh_scene` and `caster.top` are valid and committed where
            // needed; the transform pointer is 12 contiguous `f32` (`[[f32; 4]; 3]`) in
            // row-major 3×4 order, read during the call. The instance geometry is released
            // after attaching; the top scene keeps its own reference.
            unsafe {
                let geom = sys::rtcNewGeometry(device, sys::RTC_GEOMETRY_TYPE_INSTANCE);
                caster.check("rtcNewGeometry(INSTANCE)")?;
                sys::rtcSetGeometryInstancedScene(geom, mesh_scene);
                sys::rtcSetGeometryTransform(
                    geom,
                    0,
                    sys::RTC_FORMAT_FLOAT3X4_ROW_MAJOR,
                    instance.scene_from_mesh.rows.as_ptr() as *const c_void,
                );
                sys::rtcCommitGeometry(geom);
                sys::rtcAttachGeometryByID(caster.top, geom, id);
                sys::rtcReleaseGeometry(geom);
            }
        }
        // SAFETY: `caster.top` is a valid scene; all its geometries are committed.
        unsafe { sys::rtcCommitScene(caster.top) };
        caster.check("building the top scene")?;
        Ok(caster)
    }

    /// The packet mode in use (never [`PacketMode::Auto`]).
    pub fn packet_mode(&self) -> PacketMode {
        self.mode
    }

    /// Whether this Embree build runs 4-, 8- and 16-wide packets natively on this CPU.
    pub fn native_packet_widths(&self) -> [bool; 3] {
        self.native
    }

    /// Embree's version number, e.g. `31305` for 3.13.5.
    pub fn version(&self) -> u32 {
        u32::try_from(self.device_property(sys::RTC_DEVICE_PROPERTY_VERSION)).unwrap_or(0)
    }

    fn device_property(&self, property: u32) -> isize {
        // SAFETY: `self.device` is a valid device; properties are plain reads.
        unsafe { sys::rtcGetDeviceProperty(self.device, property) }
    }

    /// Turns a pending Embree error into an `Err`, with the callback's message.
    fn check(&self, what: &str) -> Result<(), EmbreeError> {
        // SAFETY: `self.device` is a valid device.
        let code = unsafe { sys::rtcGetDeviceError(self.device) };
        if code == sys::RTC_ERROR_NONE {
            return Ok(());
        }
        let message = self
            .state
            .first_error
            .lock()
            .ok()
            .and_then(|first| first.clone())
            .unwrap_or_else(|| format!("error code {code}"));
        Err(EmbreeError::Embree(format!("{what}: {message}")))
    }

    /// The `N`-wide packet path: `PACKET_SIZE / N` calls of `intersect`.
    fn cast_packet_n<const N: usize>(
        &self,
        intersect: sys::IntersectN,
        packet: &RayPacket,
        (t_near, t_far): (f32, f32),
        hits: &mut [Hit; PACKET_SIZE],
    ) {
        let mut context = sys::RTCIntersectContext::new(sys::RTC_INTERSECT_CONTEXT_FLAG_COHERENT);
        for base in (0..packet.len).step_by(N) {
            let mut valid = sys::ValidMask([0i32; N]);
            let mut rh = sys::RTCRayHitN::<N>::new(packet.origin, t_near, t_far);
            let lanes = N.min(packet.len - base);
            for k in 0..lanes {
                let d = [
                    packet.dir[0][base + k],
                    packet.dir[1][base + k],
                    packet.dir[2][base + k],
                ];
                if usable_direction(d) {
                    valid.0[k] = -1;
                    rh.dir_x[k] = d[0];
                    rh.dir_y[k] = d[1];
                    rh.dir_z[k] = d[2];
                }
            }
            // SAFETY: `intersect` is the `rtcIntersect{N}` entry point matching `N` (chosen
            // in `cast_packet`); `rh` has the C layout of `RTCRayHit{N}` with the required
            // alignment (checked at compile time); `valid` holds `N` ints, 64-byte aligned; the scene is
            // committed; every valid ray has finite origin and direction, `0 <= tnear <=
            // tfar`, and `geomID` set to invalid, as Embree requires.
            unsafe {
                intersect(
                    valid.0.as_ptr(),
                    self.top,
                    &mut context,
                    &mut rh as *mut sys::RTCRayHitN<N> as *mut c_void,
                );
            }
            for k in 0..lanes {
                hits[base + k] = if valid.0[k] != 0 {
                    lane_hit(&rh, k)
                } else {
                    Hit::MISS
                };
            }
        }
    }

    /// The coherent ray-stream path: one `rtcIntersectNp` over the packet.
    fn cast_packet_stream(
        &self,
        packet: &RayPacket,
        (t_near, t_far): (f32, f32),
        hits: &mut [Hit; PACKET_SIZE],
    ) {
        let mut context = sys::RTCIntersectContext::new(sys::RTC_INTERSECT_CONTEXT_FLAG_COHERENT);
        let mut rh = sys::RTCRayHitN::<PACKET_SIZE>::new(packet.origin, t_near, t_far);
        rh.dir_x = packet.dir[0];
        rh.dir_y = packet.dir[1];
        rh.dir_z = packet.dir[2];
        let mut usable = [true; PACKET_SIZE];
        for (k, usable) in usable.iter_mut().enumerate().take(packet.len) {
            let d = [rh.dir_x[k], rh.dir_y[k], rh.dir_z[k]];
            if !usable_direction(d) {
                // A stream has no valid mask: trace a harmless empty segment instead.
                *usable = false;
                rh.dir_x[k] = 0.0;
                rh.dir_y[k] = 0.0;
                rh.dir_z[k] = 1.0;
                rh.tfar[k] = t_near;
            }
        }
        let np = sys::RTCRayHitNp {
            org_x: rh.org_x.as_mut_ptr(),
            org_y: rh.org_y.as_mut_ptr(),
            org_z: rh.org_z.as_mut_ptr(),
            tnear: rh.tnear.as_mut_ptr(),
            dir_x: rh.dir_x.as_mut_ptr(),
            dir_y: rh.dir_y.as_mut_ptr(),
            dir_z: rh.dir_z.as_mut_ptr(),
            time: rh.time.as_mut_ptr(),
            tfar: rh.tfar.as_mut_ptr(),
            mask: rh.mask.as_mut_ptr(),
            id: rh.id.as_mut_ptr(),
            flags: rh.flags.as_mut_ptr(),
            ng_x: rh.ng_x.as_mut_ptr(),
            ng_y: rh.ng_y.as_mut_ptr(),
            ng_z: rh.ng_z.as_mut_ptr(),
            u: rh.u.as_mut_ptr(),
            v: rh.v.as_mut_ptr(),
            prim_id: rh.prim_id.as_mut_ptr(),
            geom_id: rh.geom_id.as_mut_ptr(),
            inst_id: [rh.inst_id[0].as_mut_ptr()],
        };
        // SAFETY: every pointer in `np` addresses a distinct array of `PACKET_SIZE >=
        // packet.len` lanes in `rh`, which outlives the call and is not otherwise accessed
        // during it; the scene is committed; the first `packet.len` rays have finite
        // origin and direction, `0 <= tnear <= tfar` and `geomID` invalid.
        unsafe {
            sys::rtcIntersectNp(self.top, &mut context, &np, packet.len as u32);
        }
        for k in 0..packet.len {
            hits[k] = if usable[k] {
                lane_hit(&rh, k)
            } else {
                Hit::MISS
            };
        }
    }

    fn intersect1(
        &self,
        context: &mut sys::RTCIntersectContext,
        origin: [f32; 3],
        dir: [f32; 3],
        (t_near, t_far): (f32, f32),
    ) -> Hit {
        let mut rh = sys::RTCRayHit {
            org_x: origin[0],
            org_y: origin[1],
            org_z: origin[2],
            tnear: t_near,
            dir_x: dir[0],
            dir_y: dir[1],
            dir_z: dir[2],
            time: 0.0,
            tfar: t_far,
            mask: u32::MAX,
            id: 0,
            flags: 0,
            ng_x: 0.0,
            ng_y: 0.0,
            ng_z: 0.0,
            u: 0.0,
            v: 0.0,
            prim_id: sys::RTC_INVALID_GEOMETRY_ID,
            geom_id: sys::RTC_INVALID_GEOMETRY_ID,
            inst_id: [sys::RTC_INVALID_GEOMETRY_ID],
        };
        // SAFETY: `rh` is a 16-byte aligned `RTCRayHit` with finite origin and direction,
        // `0 <= tnear <= tfar` and `geomID` invalid (checked by the callers); the scene is
        // committed.
        unsafe { sys::rtcIntersect1(self.top, context, &mut rh) };
        if rh.geom_id == sys::RTC_INVALID_GEOMETRY_ID {
            Hit::MISS
        } else {
            Hit {
                t: rh.tfar,
                instance: rh.inst_id[0],
                prim: rh.prim_id,
                u: rh.u,
                v: rh.v,
            }
        }
    }
}

/// Lane `k` of a traced packet as a [`Hit`].
fn lane_hit<const N: usize>(rh: &sys::RTCRayHitN<N>, k: usize) -> Hit {
    if rh.geom_id[k] == sys::RTC_INVALID_GEOMETRY_ID {
        return Hit::MISS;
    }
    Hit {
        t: rh.tfar[k],
        instance: rh.inst_id[0][k],
        prim: rh.prim_id[k],
        u: rh.u[k],
        v: rh.v[k],
    }
}

/// Embree needs a finite, non-zero direction.
fn usable_direction(d: [f32; 3]) -> bool {
    d.iter().all(|c| c.is_finite()) && d.iter().any(|&c| c != 0.0)
}

/// The ray segment as Embree needs it (`0 <= tnear <= tfar`), or `None` when it is empty.
fn segment(origin: [f32; 3], t_min: f32, t_max: f32) -> Option<(f32, f32)> {
    let t_near = t_min.max(0.0);
    (origin.iter().all(|c| c.is_finite()) && t_near <= t_max).then_some((t_near, t_max))
}

/// What Embree must not see: instances of missing meshes or with singular transforms
/// (NaNs in traversal), indices past the positions (out-of-bounds reads).
fn validate(scene: &TraceScene) -> Result<(), EmbreeError> {
    for (m, mesh) in scene.meshes.iter().enumerate() {
        let n = mesh.positions.len();
        if u32::try_from(n).is_err() {
            return Err(EmbreeError::InvalidScene(format!(
                "mesh {m} has too many vertices"
            )));
        }
        if let Some((t, tri)) = mesh
            .indices
            .iter()
            .enumerate()
            .find(|(_, tri)| tri.iter().any(|&i| i as usize >= n))
        {
            return Err(EmbreeError::InvalidScene(format!(
                "mesh {m} triangle {t} {tri:?} indexes past its {n} positions"
            )));
        }
    }
    for (i, instance) in scene.instances.iter().enumerate() {
        if instance.mesh as usize >= scene.meshes.len() {
            return Err(EmbreeError::InvalidScene(format!(
                "instance {i} names mesh {} of {}",
                instance.mesh,
                scene.meshes.len()
            )));
        }
        if !transform_ok(&instance.scene_from_mesh) {
            return Err(EmbreeError::InvalidScene(format!(
                "instance {i} has a singular or non-finite transform"
            )));
        }
    }
    Ok(())
}

fn transform_ok(m: &Affine3) -> bool {
    m.rows.iter().flatten().all(|c| c.is_finite()) && m.inverse().is_some()
}

impl RayCaster for EmbreeCaster {
    fn name(&self) -> &'static str {
        "embree"
    }

    fn cast_packet(&self, packet: &RayPacket, hits: &mut [Hit; PACKET_SIZE]) {
        let len = packet.len.min(PACKET_SIZE);
        if len == 0 {
            return;
        }
        let Some(range) = segment(packet.origin, packet.t_min, packet.t_max) else {
            hits[..len].fill(Hit::MISS);
            return;
        };
        if len < packet.len {
            // Lanes past PACKET_SIZE cannot exist; keep the stream call in bounds anyway.
            let mut clipped = packet.clone();
            clipped.len = len;
            return self.cast_packet(&clipped, hits);
        }
        match self.mode {
            PacketMode::Packet16 => {
                self.cast_packet_n::<16>(sys::rtcIntersect16, packet, range, hits);
            }
            PacketMode::Packet8 => {
                self.cast_packet_n::<8>(sys::rtcIntersect8, packet, range, hits);
            }
            PacketMode::Packet4 | PacketMode::Auto => {
                self.cast_packet_n::<4>(sys::rtcIntersect4, packet, range, hits);
            }
            PacketMode::Stream => self.cast_packet_stream(packet, range, hits),
            PacketMode::Single => {
                let mut context =
                    sys::RTCIntersectContext::new(sys::RTC_INTERSECT_CONTEXT_FLAG_COHERENT);
                for (k, hit) in hits[..len].iter_mut().enumerate() {
                    let d = [packet.dir[0][k], packet.dir[1][k], packet.dir[2][k]];
                    *hit = if usable_direction(d) {
                        self.intersect1(&mut context, packet.origin, d, range)
                    } else {
                        Hit::MISS
                    };
                }
            }
        }
    }

    fn cast_ray(&self, origin: [f32; 3], dir: [f32; 3], t_min: f32, t_max: f32) -> Hit {
        match segment(origin, t_min, t_max) {
            Some(range) if usable_direction(dir) => {
                let mut context =
                    sys::RTCIntersectContext::new(sys::RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT);
                self.intersect1(&mut context, origin, dir, range)
            }
            _ => Hit::MISS,
        }
    }

    fn memory_bytes(&self) -> usize {
        let total = self.state.memory.load(Ordering::Relaxed).max(0) as usize;
        total.saturating_sub(self.geometry_bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Instance, MeshGeometry};
    use nalgebra::{Matrix3, Rotation3, Unit, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Brute-force first hit in `f64`, with the smallest barycentric coordinate of the hit
    /// (how close it is to an edge).
    struct RefHit {
        t: f64,
        instance: u32,
        prim: u32,
        margin: f64,
    }

    fn affine_f64(a: &Affine3) -> (Matrix3<f64>, Vector3<f64>) {
        let m = Matrix3::from_fn(|i, j| f64::from(a.rows[i][j]));
        let t = Vector3::from_fn(|i, _| f64::from(a.rows[i][3]));
        (m, t)
    }

    /// Möller–Trumbore in `f64`; `(t, u, v)` with `u`, `v` the 2nd/3rd vertex weights.
    fn intersect_triangle(
        o: Vector3<f64>,
        d: Vector3<f64>,
        p: [Vector3<f64>; 3],
        slack: f64,
    ) -> Option<(f64, f64, f64)> {
        let e1 = p[1] - p[0];
        let e2 = p[2] - p[0];
        let pv = d.cross(&e2);
        let det = e1.dot(&pv);
        if det.abs() < 1e-300 {
            return None;
        }
        let s = o - p[0];
        let u = s.dot(&pv) / det;
        let q = s.cross(&e1);
        let v = d.dot(&q) / det;
        let t = e2.dot(&q) / det;
        (u >= -slack && v >= -slack && u + v <= 1.0 + slack).then_some((t, u, v))
    }

    fn triangle_in_scene(scene: &TraceScene, instance: u32, prim: u32) -> [Vector3<f64>; 3] {
        let inst = &scene.instances[instance as usize];
        let mesh = &scene.meshes[inst.mesh as usize];
        let (m, t) = affine_f64(&inst.scene_from_mesh);
        mesh.indices[prim as usize].map(|i| {
            let p = mesh.positions[i as usize];
            m * Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) + t
        })
    }

    fn brute_force(
        scene: &TraceScene,
        origin: [f32; 3],
        dir: [f32; 3],
        t_min: f32,
        t_max: f32,
    ) -> Option<RefHit> {
        let o = Vector3::from(origin.map(f64::from));
        let d = Vector3::from(dir.map(f64::from));
        let mut best: Option<RefHit> = None;
        for (i, inst) in scene.instances.iter().enumerate() {
            let mesh = &scene.meshes[inst.mesh as usize];
            for prim in 0..mesh.indices.len() {
                let p = triangle_in_scene(scene, i as u32, prim as u32);
                if let Some((t, u, v)) = intersect_triangle(o, d, p, 0.0)
                    && t >= f64::from(t_min)
                    && t <= f64::from(t_max)
                    && best.as_ref().is_none_or(|b| t < b.t)
                {
                    best = Some(RefHit {
                        t,
                        instance: i as u32,
                        prim: prim as u32,
                        margin: u.min(v).min(1.0 - u - v),
                    });
                }
            }
        }
        best
    }

    /// Random triangle soups plus a shared-vertex grid, placed by random instances with
    /// rotation, per-axis scale and translation.
    fn random_scene(seed: u64, meshes: usize, instances: usize) -> TraceScene {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut scene = TraceScene::default();
        for _ in 0..meshes {
            let n = rng.random_range(20..80);
            let mut mesh = MeshGeometry::default();
            for _ in 0..n {
                let c: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
                for _ in 0..3 {
                    let j = mesh.positions.len() as u32;
                    let _ = j;
                    mesh.positions
                        .push(std::array::from_fn(|a| c[a] + rng.random_range(-0.4..0.4)));
                }
                let j = mesh.positions.len() as u32;
                mesh.indices.push([j - 3, j - 2, j - 1]);
            }
            scene.meshes.push(mesh);
        }
        scene.meshes.push(grid_mesh(6, 0.25));
        // An empty mesh, never hit.
        scene.meshes.push(MeshGeometry::default());
        for _ in 0..instances {
            let axis = Unit::new_normalize(Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0)));
            let rot =
                Rotation3::from_axis_angle(&axis, rng.random_range(0.0..std::f64::consts::TAU));
            let scale = Vector3::from_fn(|_, _| rng.random_range(0.3..3.0));
            let m = rot.matrix() * Matrix3::from_diagonal(&scale);
            let t = Vector3::from_fn(|_, _| rng.random_range(-8.0..8.0));
            scene.instances.push(Instance {
                mesh: rng.random_range(0..scene.meshes.len() as u32),
                scene_from_mesh: Affine3 {
                    rows: std::array::from_fn(|i| {
                        [
                            m[(i, 0)] as f32,
                            m[(i, 1)] as f32,
                            m[(i, 2)] as f32,
                            t[i] as f32,
                        ]
                    }),
                },
            });
        }
        scene
    }

    /// An `n`×`n` height-field grid of quads (two triangles each) with shared vertices.
    fn grid_mesh(n: u32, cell: f32) -> MeshGeometry {
        let mut mesh = MeshGeometry::default();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 * cell, j as f32 * cell);
                mesh.positions.push([x, y, 0.1 * (x * 3.0).sin() * y]);
            }
        }
        for j in 0..n {
            for i in 0..n {
                let a = j * (n + 1) + i;
                mesh.indices.push([a, a + 1, a + n + 2]);
                mesh.indices.push([a, a + n + 2, a + n + 1]);
            }
        }
        mesh
    }

    fn random_ray(rng: &mut ChaCha8Rng) -> ([f32; 3], [f32; 3]) {
        let o: [f32; 3] = std::array::from_fn(|_| rng.random_range(-14.0..14.0));
        let target: [f32; 3] = std::array::from_fn(|_| rng.random_range(-8.0..8.0));
        // Non-unit directions: t is in units of the direction's length.
        let len = rng.random_range(0.5..2.0);
        let d = Vector3::from_fn(|i, _| target[i] - o[i]).normalize() * len;
        (o, [d.x, d.y, d.z])
    }

    fn assert_matches_reference(scene: &TraceScene, caster: &EmbreeCaster, rays: usize) {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut hits, mut grazing) = (0, 0);
        for r in 0..rays {
            let (o, d) = random_ray(&mut rng);
            let (t_min, t_max) = if r % 5 == 0 {
                (2.0, 15.0)
            } else {
                (0.0, f32::INFINITY)
            };
            let got = caster.cast_ray(o, d, t_min, t_max);
            let want = brute_force(scene, o, d, t_min, t_max);
            match (&want, got.is_hit()) {
                (None, false) => {}
                (Some(w), true) => {
                    hits += 1;
                    let t = f64::from(got.t);
                    assert!(
                        (t - w.t).abs() <= 1e-4 * w.t.max(1e-3),
                        "ray {r}: t {t} vs reference {}",
                        w.t
                    );
                    if (got.instance, got.prim) != (w.instance, w.prim) {
                        // A tie (shared edge, overlapping triangles): Embree's triangle must
                        // be hit at the same distance too.
                        let p = triangle_in_scene(scene, got.instance, got.prim);
                        let o64 = Vector3::from(o.map(f64::from));
                        let d64 = Vector3::from(d.map(f64::from));
                        let (t2, _, _) = intersect_triangle(o64, d64, p, 1e-4)
                            .unwrap_or_else(|| panic!("ray {r}: Embree's triangle not hit"));
                        assert!(
                            (t2 - w.t).abs() <= 1e-4 * w.t.max(1e-3),
                            "ray {r}: ({}, {}) at {t2} vs reference ({}, {}) at {}",
                            got.instance,
                            got.prim,
                            w.instance,
                            w.prim,
                            w.t
                        );
                    } else {
                        let p = triangle_in_scene(scene, got.instance, got.prim);
                        let (_, u, v) = intersect_triangle(
                            Vector3::from(o.map(f64::from)),
                            Vector3::from(d.map(f64::from)),
                            p,
                            1.0,
                        )
                        .unwrap_or_else(|| panic!("ray {r}: parallel"));
                        assert!(
                            (f64::from(got.u) - u).abs() < 1e-3
                                && (f64::from(got.v) - v).abs() < 1e-3,
                            "ray {r}: barycentrics ({}, {}) vs ({u}, {v})",
                            got.u,
                            got.v
                        );
                    }
                }
                (Some(w), false) => {
                    assert!(
                        w.margin < 1e-5,
                        "ray {r}: Embree missed a hit at t {} (margin {})",
                        w.t,
                        w.margin
                    );
                    grazing += 1;
                }
                (None, true) => {
                    // Only a grazing hit on an edge the f64 reference just missed.
                    let p = triangle_in_scene(scene, got.instance, got.prim);
                    let o64 = Vector3::from(o.map(f64::from));
                    let d64 = Vector3::from(d.map(f64::from));
                    assert!(
                        intersect_triangle(o64, d64, p, 1e-5).is_some(),
                        "ray {r}: Embree hit ({}, {}) at {} but the reference misses",
                        got.instance,
                        got.prim,
                        got.t
                    );
                    grazing += 1;
                }
            }
        }
        assert!(hits > rays / 4, "only {hits} of {rays} rays hit");
        assert!(
            grazing <= rays / 1000 + 1,
            "{grazing} grazing disagreements"
        );
    }

    #[test]
    fn single_rays_match_brute_force() {
        let scene = random_scene(1, 5, 40);
        for robust in [true, false] {
            let options = EmbreeOptions {
                robust,
                ..EmbreeOptions::default()
            };
            let caster = EmbreeCaster::with_options(&scene, &options).expect("embree");
            assert_eq!(caster.name(), "embree");
            assert!(caster.memory_bytes() > 0);
            assert_matches_reference(&scene, &caster, 3000);
        }
    }

    fn random_packet(rng: &mut ChaCha8Rng, len: usize) -> RayPacket {
        let (origin, _) = random_ray(rng);
        let mut packet = RayPacket {
            origin,
            dir: [[0.0; PACKET_SIZE]; 3],
            len,
            t_min: 0.0,
            t_max: f32::INFINITY,
        };
        // A cone of directions towards the scene, like a camera tile (but wider).
        let centre = Vector3::from_fn(|i, _| -origin[i]).normalize();
        for k in 0..PACKET_SIZE {
            let d = (centre + Vector3::from_fn(|_, _| rng.random_range(-0.25..0.25)))
                * rng.random_range(0.5..2.0);
            for a in 0..3 {
                packet.dir[a][k] = d[a];
            }
        }
        packet
    }

    #[test]
    fn packets_match_single_rays_in_every_mode() {
        let scene = random_scene(2, 4, 60);
        let modes = [
            PacketMode::Auto,
            PacketMode::Single,
            PacketMode::Packet4,
            PacketMode::Packet8,
            PacketMode::Packet16,
            PacketMode::Stream,
        ];
        for mode in modes {
            let options = EmbreeOptions {
                packet_mode: mode,
                ..EmbreeOptions::default()
            };
            let caster = EmbreeCaster::with_options(&scene, &options).expect("embree");
            assert_ne!(caster.packet_mode(), PacketMode::Auto);
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            let mut hit_count = 0;
            for p in 0..200 {
                let len = if p % 7 == 0 {
                    rng.random_range(1..PACKET_SIZE)
                } else {
                    PACKET_SIZE
                };
                let mut packet = random_packet(&mut rng, len);
                if p % 11 == 0 {
                    packet.t_min = 3.0;
                    packet.t_max = 12.0;
                }
                let sentinel = Hit {
                    t: -1.0,
                    instance: 12345,
                    prim: 0,
                    u: 0.0,
                    v: 0.0,
                };
                let mut hits = [sentinel; PACKET_SIZE];
                caster.cast_packet(&packet, &mut hits);
                for (k, hit) in hits.iter().enumerate() {
                    if k >= len {
                        assert_eq!(*hit, sentinel, "{mode:?}: lane {k} past len written");
                        continue;
                    }
                    let d = [packet.dir[0][k], packet.dir[1][k], packet.dir[2][k]];
                    let single = caster.cast_ray(packet.origin, d, packet.t_min, packet.t_max);
                    hit_count += usize::from(single.is_hit());
                    // Embree's packet, stream and single-ray kernels run the same
                    // arithmetic: results are bit-identical.
                    assert_eq!(*hit, single, "{mode:?} packet {p} lane {k}");
                }
            }
            assert!(hit_count > 2000, "{mode:?}: only {hit_count} hits");
        }
    }

    #[test]
    fn rays_through_shared_edges_and_vertices_never_slip_through() {
        // A grid instanced with rotation and non-uniform scale; rays aimed exactly at every
        // vertex and edge midpoint of the mesh (mapped to the scene) must all hit.
        let n = 16;
        let mesh = grid_mesh(n, 0.125);
        let rot = Rotation3::from_euler_angles(0.3, -0.2, 0.7);
        let m = rot.matrix() * Matrix3::from_diagonal(&Vector3::new(2.0, 0.7, 1.3));
        let inst = Affine3 {
            rows: std::array::from_fn(|i| {
                [
                    m[(i, 0)] as f32,
                    m[(i, 1)] as f32,
                    m[(i, 2)] as f32,
                    [1.0, -2.0, 0.5][i],
                ]
            }),
        };
        let scene = TraceScene {
            meshes: vec![mesh.clone()],
            instances: vec![Instance {
                mesh: 0,
                scene_from_mesh: inst,
            }],
            ..TraceScene::default()
        };
        let caster = EmbreeCaster::new(&scene).expect("embree");
        let mut targets = Vec::new();
        for tri in &mesh.indices {
            for e in 0..3 {
                let a = mesh.positions[tri[e] as usize];
                let b = mesh.positions[tri[(e + 1) % 3] as usize];
                targets.push(a);
                for f in [0.5f32, 0.25, 0.8] {
                    targets.push(std::array::from_fn(|c| a[c] + f * (b[c] - a[c])));
                }
            }
        }
        // Points on the grid's outer border may rightly be missed.
        let side = n as f32 * 0.125;
        targets.retain(|p| p[0] > 0.0 && p[0] < side && p[1] > 0.0 && p[1] < side);
        assert!(targets.len() > 10 * mesh.indices.len());
        let normal = inst.vector([0.0, 0.0, 1.0]);
        let origins = [
            inst.point([1.0, 1.0, 3.0]),
            inst.point([-0.3, 2.5, -2.0]),
            [normal[0] * 5.0, normal[1] * 5.0 + 0.3, normal[2] * 5.0],
        ];
        let mut missed = 0;
        let mut total = 0;
        for origin in origins {
            for target in &targets {
                let p = inst.point(*target);
                let d = [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]];
                total += 1;
                if !caster.cast_ray(origin, d, 0.0, 2.0).is_hit() {
                    missed += 1;
                }
            }
        }
        assert_eq!(missed, 0, "{missed} of {total} rays slipped through");
    }

    /// One unit-direction pinhole view (`width`×`height`, 87° horizontal field of view) of
    /// [`synthetic_vegetation_scene`](crate::render::trace::synthetic_vegetation_scene):
    /// 1.2 m above the ground in the inter-row between rows 2 and 3, looking along them,
    /// pitched slightly down, as 8×8 tiles.
    pub(super) fn vegetation_view(width: usize, height: usize) -> Vec<RayPacket> {
        let origin = [-1.5f32, 6.25, 1.2];
        let pitch = -0.06f32;
        let fwd = Vector3::new(pitch.cos(), 0.0, pitch.sin());
        let right = fwd.cross(&Vector3::z()).normalize();
        let up = right.cross(&fwd);
        let f = 0.5 * width as f32 / (0.5 * 87f32.to_radians()).tan();
        let mut packets = Vec::new();
        for ty in (0..height).step_by(8) {
            for tx in (0..width).step_by(8) {
                let mut p = RayPacket {
                    origin,
                    dir: [[0.0; PACKET_SIZE]; 3],
                    len: 0,
                    t_min: 0.0,
                    t_max: f32::INFINITY,
                };
                for py in ty..(ty + 8).min(height) {
                    for px in tx..(tx + 8).min(width) {
                        let x = (px as f32 + 0.5 - 0.5 * width as f32) / f;
                        let y = (py as f32 + 0.5 - 0.5 * height as f32) / f;
                        let d = (fwd + right * x - up * y).normalize();
                        for a in 0..3 {
                            p.dir[a][p.len] = d[a];
                        }
                        p.len += 1;
                    }
                }
                packets.push(p);
            }
        }
        packets
    }

    #[test]
    fn depth_matches_the_default_backend() {
        use crate::render::build_default;
        use crate::render::trace::synthetic_vegetation_scene;
        let scene = synthetic_vegetation_scene(3, 200_000);
        let embree = EmbreeCaster::new(&scene).expect("embree");
        let bvh = build_default(&scene);
        let packets = vegetation_view(320, 240);
        let (mut rays, mut agree, mut hits) = (0usize, 0usize, 0usize);
        for packet in &packets {
            let mut a = [Hit::MISS; PACKET_SIZE];
            let mut b = [Hit::MISS; PACKET_SIZE];
            embree.cast_packet(packet, &mut a);
            bvh.cast_packet(packet, &mut b);
            for (a, b) in a.iter().zip(&b).take(packet.len) {
                rays += 1;
                hits += usize::from(a.is_hit());
                let same = match (a.is_hit(), b.is_hit()) {
                    (true, true) => (a.t - b.t).abs() <= 1e-3,
                    (false, false) => true,
                    _ => false,
                };
                agree += usize::from(same);
            }
        }
        println!(
            "embree vs {}: {agree} of {rays} rays agree, {hits} hits",
            bvh.name()
        );
        assert_eq!(rays, 320 * 240);
        assert!(hits > rays / 2, "only {hits} of {rays} rays hit");
        assert!(
            agree as f64 >= 0.999 * rays as f64,
            "{} backends agree on depth within 1 mm for {agree} of {rays} rays",
            bvh.name()
        );
    }

    #[test]
    fn degenerate_inputs_miss_or_fail_cleanly() {
        let scene = random_scene(4, 2, 5);
        let caster = EmbreeCaster::new(&scene).expect("embree");
        let o = [0.0, 0.0, 20.0];
        assert!(!caster.cast_ray(o, [0.0; 3], 0.0, f32::INFINITY).is_hit());
        assert!(!caster.cast_ray(o, [f32::NAN, 0.0, -1.0], 0.0, 1e9).is_hit());
        assert!(
            !caster
                .cast_ray([f32::NAN; 3], [0.0, 0.0, -1.0], 0.0, 1e9)
                .is_hit()
        );
        assert!(!caster.cast_ray(o, [0.0, 0.0, -1.0], 5.0, 4.0).is_hit());
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut packet = random_packet(&mut rng, PACKET_SIZE);
        packet.dir[0][3] = 0.0;
        packet.dir[1][3] = 0.0;
        packet.dir[2][3] = 0.0;
        packet.dir[1][9] = f32::INFINITY;
        for mode in [PacketMode::Packet16, PacketMode::Stream, PacketMode::Single] {
            let options = EmbreeOptions {
                packet_mode: mode,
                ..EmbreeOptions::default()
            };
            let caster = EmbreeCaster::with_options(&scene, &options).expect("embree");
            let mut hits = [Hit::MISS; PACKET_SIZE];
            caster.cast_packet(&packet, &mut hits);
            assert!(!hits[3].is_hit() && !hits[9].is_hit(), "{mode:?}");
        }
        // A scene without instances, and invalid scenes.
        let empty = EmbreeCaster::new(&TraceScene::default()).expect("embree");
        assert!(!empty.cast_ray(o, [0.0, 0.0, -1.0], 0.0, 1e9).is_hit());
        let mut bad = scene.clone();
        bad.instances[0].mesh = 99;
        assert!(matches!(
            EmbreeCaster::new(&bad),
            Err(EmbreeError::InvalidScene(_))
        ));
        let mut bad = scene.clone();
        bad.instances[0].scene_from_mesh.rows[2] = [0.0; 4];
        assert!(matches!(
            EmbreeCaster::new(&bad),
            Err(EmbreeError::InvalidScene(_))
        ));
        let mut bad = scene;
        bad.meshes[0].indices[0][1] = 1_000_000;
        assert!(matches!(
            EmbreeCaster::new(&bad),
            Err(EmbreeError::InvalidScene(_))
        ));
        let options = EmbreeOptions {
            device_config: "no_such_option=1".into(),
            ..EmbreeOptions::default()
        };
        // Embree rejects unknown options or ignores them; either way no crash.
        let _ = EmbreeCaster::with_options(&TraceScene::default(), &options);
    }

    #[test]
    fn caster_is_send_and_sync_and_thread_safe() {
        fn assert_send_sync<T: Send + Sync>() {}
        assert_send_sync::<EmbreeCaster>();
        let scene = random_scene(6, 3, 30);
        let caster = EmbreeCaster::new(&scene).expect("embree");
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let packets: Vec<RayPacket> = (0..64)
            .map(|_| random_packet(&mut rng, PACKET_SIZE))
            .collect();
        let serial: Vec<[Hit; PACKET_SIZE]> = packets
            .iter()
            .map(|p| {
                let mut h = [Hit::MISS; PACKET_SIZE];
                caster.cast_packet(p, &mut h);
                h
            })
            .collect();
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for (p, want) in packets.iter().zip(&serial) {
                        let mut h = [Hit::MISS; PACKET_SIZE];
                        caster.cast_packet(p, &mut h);
                        assert_eq!(&h, want);
                    }
                });
            }
        });
    }
}

#[cfg(test)]
mod throughput {
    //! Benchmarks, ignored by default: `cargo test --release -p vinebench-sim --features
    //! embree --lib render::embree::throughput -- --ignored --nocapture --test-threads=1`.
    use super::*;
    use crate::render::build_default;
    use crate::render::trace::{measure_mrays, measure_mrays_single, synthetic_vegetation_scene};
    use std::time::Instant;

    /// The project's benchmark ([`measure_mrays`], rayon over tiles) for Embree and the
    /// default backend, on one thread and on rayon's default pool; runs interleaved over
    /// rounds, best round counts.
    #[test]
    #[ignore = "benchmark; run in release with --ignored --nocapture"]
    fn measure_mrays_vegetation() {
        let scene = synthetic_vegetation_scene(1, 1_500_000);
        let start = Instant::now();
        let embree = EmbreeCaster::new(&scene).expect("embree");
        let embree_build = start.elapsed().as_secs_f64();
        let start = Instant::now();
        let bvh = build_default(&scene);
        let bvh_build = start.elapsed().as_secs_f64();
        let casters: [(&dyn RayCaster, f64); 2] = [(&embree, embree_build), (&*bvh, bvh_build)];
        println!(
            "embree {}, mode {:?}, native 4/8/16 {:?}",
            embree.version(),
            embree.packet_mode(),
            embree.native_packet_widths()
        );
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool");
        let threads = rayon::current_num_threads();
        // [caster][threads 1 / default][packet / single]
        let mut best = [[[0.0f64; 2]; 2]; 2];
        for _ in 0..4 {
            for (c, (caster, _)) in casters.iter().enumerate() {
                for (t, pool) in [Some(&one), None].into_iter().enumerate() {
                    let run = |single: bool| {
                        let f = || {
                            if single {
                                measure_mrays_single(*caster, &scene, 640, 480, 4)
                            } else {
                                measure_mrays(*caster, &scene, 640, 480, 4)
                            }
                        };
                        pool.map_or_else(f, |p| p.install(f))
                    };
                    best[c][t][0] = best[c][t][0].max(run(false));
                    best[c][t][1] = best[c][t][1].max(run(true));
                }
            }
        }
        for (c, (caster, build)) in casters.iter().enumerate() {
            println!(
                "{:6}: build {build:.2} s, {:.1} MiB; 1 thread: cast_packet {:.2}, cast_ray \
                 {:.2} Mrays/s; {threads} threads: cast_packet {:.2}, cast_ray {:.2} Mrays/s",
                caster.name(),
                caster.memory_bytes() as f64 / f64::from(1 << 20),
                best[c][0][0],
                best[c][0][1],
                best[c][1][0],
                best[c][1][1],
            );
        }
    }

    /// Seconds for one single-threaded pass over `packets`, and the hit count.
    fn pass(caster: &EmbreeCaster, packets: &[RayPacket], single: bool) -> (f64, usize) {
        let mut hits = [Hit::MISS; PACKET_SIZE];
        let mut hit_count = 0;
        let start = Instant::now();
        for p in packets {
            if single {
                for (k, hit) in hits.iter_mut().enumerate().take(p.len) {
                    let d = [p.dir[0][k], p.dir[1][k], p.dir[2][k]];
                    *hit = caster.cast_ray(p.origin, d, p.t_min, p.t_max);
                }
            } else {
                caster.cast_packet(p, &mut hits);
            }
            hit_count += hits[..p.len].iter().filter(|h| h.is_hit()).count();
        }
        (start.elapsed().as_secs_f64(), hit_count)
    }

    /// Single-threaded Mrays/s of every packet mode (and of `cast_ray`) under each ISA
    /// Embree can be capped to, robust or not; configurations are interleaved over rounds
    /// and the best round counts, so load from other processes biases none of them.
    #[test]
    #[ignore = "benchmark; run in release with --ignored --nocapture"]
    fn throughput_by_packet_mode() {
        let scene = synthetic_vegetation_scene(1, 1_500_000);
        let packets = super::tests::vegetation_view(640, 480);
        let rays: usize = packets.iter().map(|p| p.len).sum();
        let modes = [
            PacketMode::Packet16,
            PacketMode::Packet8,
            PacketMode::Packet4,
            PacketMode::Stream,
            PacketMode::Single,
        ];
        let mut runs = Vec::new();
        for config in ["", "max_isa=avx2", "max_isa=sse4.2"] {
            for robust in [true, false] {
                for mode in modes {
                    let options = EmbreeOptions {
                        packet_mode: mode,
                        robust,
                        device_config: config.to_string(),
                    };
                    let caster = EmbreeCaster::with_options(&scene, &options).expect("embree");
                    // `Single` also times `cast_ray` (rtcIntersect1, incoherent context).
                    runs.push((config, robust, mode, false, caster, f64::INFINITY, 0));
                    if mode == PacketMode::Single {
                        let caster = EmbreeCaster::with_options(&scene, &options).expect("embree");
                        runs.push((config, robust, mode, true, caster, f64::INFINITY, 0));
                    }
                }
            }
        }
        for _ in 0..5 {
            for (_, _, _, single, caster, best, hits) in &mut runs {
                let (secs, h) = pass(caster, &packets, *single);
                *best = best.min(secs);
                *hits = h;
            }
        }
        println!("{rays} rays per pass");
        for (config, robust, mode, single, caster, best, hits) in &runs {
            let what = if *single {
                "cast_ray".to_string()
            } else {
                format!("{mode:?}")
            };
            println!(
                "isa {:8} robust {robust:5} {what:9} native {:?}: {:6.2} Mrays/s, {hits} hits",
                config.trim_start_matches("max_isa="),
                caster.native_packet_widths(),
                rays as f64 / best / 1e6,
            );
        }
    }
}
