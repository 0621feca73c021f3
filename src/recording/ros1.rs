//! ROS 1 messages as ROS 2 CDR: a bag's message definitions (the `message_definition`
//! every connection carries) are parsed, and each message is re-serialized field by field
//! into the CDR layout the ROS 2 decoders read: CDR alignment, strings with their
//! terminating NUL, `std_msgs/Header` without ROS 1's `seq`, type names `pkg/msg/Type`.
//! So a robot's ROS 1 bag feeds the same decoders as a ROS 2 recording (what rosbags'
//! conversion does). Nothing is trusted: counts are checked against the bytes left, the
//! nesting depth is bounded, and a definition that does not describe the bytes is an
//! error naming the field.

use std::collections::HashMap;

/// Deepest nesting of message types followed.
const MAX_DEPTH: usize = 32;

/// A field's type.
#[derive(Clone, Debug, PartialEq)]
enum Ty {
    /// A primitive of this many bytes (1, 2, 4, 8).
    Prim(usize),
    /// `string`.
    Str,
    /// `time` / `duration` (two 4-byte words).
    Time,
    /// A message type, by full name.
    Msg(String),
}

/// A field: type and array shape (`None`: scalar; `Some(None)`: `T[]`; `Some(Some(n))`:
/// `T[n]`).
#[derive(Clone, Debug, PartialEq)]
struct Field {
    name: String,
    ty: Ty,
    array: Option<Option<usize>>,
}

/// The parsed definitions of one connection: the top type and every nested one.
#[derive(Clone, Debug, Default)]
pub struct Definitions {
    top: String,
    types: HashMap<String, Vec<Field>>,
}

fn primitive(t: &str) -> Option<Ty> {
    Some(match t {
        "bool" | "int8" | "uint8" | "byte" | "char" => Ty::Prim(1),
        "int16" | "uint16" => Ty::Prim(2),
        "int32" | "uint32" | "float32" => Ty::Prim(4),
        "int64" | "uint64" | "float64" => Ty::Prim(8),
        "string" => Ty::Str,
        "time" | "duration" => Ty::Time,
        _ => return None,
    })
}

/// `sensor_msgs/Imu` → `sensor_msgs/msg/Imu` (ROS 1's `tf/tfMessage`, the same layout, →
/// `tf2_msgs/msg/TFMessage`).
pub fn ros2_type_name(ros1: &str) -> String {
    if ros1 == "tf/tfMessage" {
        return "tf2_msgs/msg/TFMessage".into();
    }
    match ros1.split_once('/') {
        Some((pkg, ty)) if !ty.starts_with("msg/") => format!("{pkg}/msg/{ty}"),
        _ => ros1.to_string(),
    }
}

impl Definitions {
    /// Parses a connection's `message_definition` for type `top` (`pkg/Type`).
    pub fn parse(top: &str, text: &str) -> Result<Definitions, String> {
        let mut types = HashMap::new();
        let mut name = top.to_string();
        let mut fields = Vec::new();
        let pkg_of = |n: &str| {
            n.split_once('/')
                .map_or(String::new(), |(p, _)| p.to_string())
        };
        let mut pkg = pkg_of(top);
        for raw in text.lines() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.starts_with("==") {
                types.insert(std::mem::take(&mut name), std::mem::take(&mut fields));
                continue;
            }
            if let Some(n) = line.strip_prefix("MSG:") {
                name = n.trim().to_string();
                pkg = pkg_of(&name);
                continue;
            }
            if line.is_empty() {
                continue;
            }
            let mut parts = line.split_whitespace();
            let (Some(ty), Some(field)) = (parts.next(), parts.next()) else {
                return Err(format!("{name}: cannot read the definition line {line:?}"));
            };
            if field.contains('=') || parts.next().is_some_and(|p| p.starts_with('=')) {
                continue; // a constant
            }
            let (base, array) = match ty.split_once('[') {
                Some((b, rest)) => {
                    let n = rest.trim_end_matches(']');
                    let len =
                        if n.is_empty() {
                            None
                        } else {
                            Some(n.parse::<usize>().map_err(|_| {
                                format!("{name}: array length {n:?} of field {field}")
                            })?)
                        };
                    (b, Some(len))
                }
                None => (ty, None),
            };
            let ty = match primitive(base) {
                Some(p) => p,
                None if base == "Header" => Ty::Msg("std_msgs/Header".into()),
                None if base.contains('/') => Ty::Msg(base.to_string()),
                None => Ty::Msg(format!("{pkg}/{base}")),
            };
            fields.push(Field {
                name: field.to_string(),
                ty,
                array,
            });
        }
        types.insert(name, fields);
        Ok(Definitions {
            top: top.to_string(),
            types,
        })
    }

    /// The CDR payload (with its encapsulation header) of a ROS 1 serialized message.
    pub fn transcode(&self, ros1: &[u8]) -> Result<Vec<u8>, String> {
        let mut t = Transcoder {
            defs: self,
            src: ros1,
            pos: 0,
            out: Vec::with_capacity(ros1.len() + 64),
        };
        t.out.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        t.message(&self.top, 0)?;
        Ok(t.out)
    }
}

struct Transcoder<'a> {
    defs: &'a Definitions,
    src: &'a [u8],
    pos: usize,
    out: Vec<u8>,
}

impl Transcoder<'_> {
    fn take(&mut self, n: usize, field: &str) -> Result<&[u8], String> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.src.len());
        let Some(end) = end else {
            return Err(format!(
                "field {field}: {n} bytes needed at byte {}, {} left",
                self.pos,
                self.src.len() - self.pos
            ));
        };
        let s = &self.src[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    /// Pads the output to a multiple of `n` after the encapsulation header.
    fn align(&mut self, n: usize) {
        while !(self.out.len() - 4).is_multiple_of(n) {
            self.out.push(0);
        }
    }

    fn u32(&mut self, field: &str) -> Result<u32, String> {
        let b = self.take(4, field)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn message(&mut self, ty: &str, depth: usize) -> Result<(), String> {
        if depth > MAX_DEPTH {
            return Err(format!("{ty}: nested deeper than {MAX_DEPTH}"));
        }
        let fields = self
            .defs
            .types
            .get(ty)
            .ok_or_else(|| format!("type {ty} is not in the message definition"))?
            .clone();
        for f in &fields {
            if ty == "std_msgs/Header" && f.name == "seq" {
                // ROS 2's Header has no seq.
                self.take(4, "header.seq")?;
                continue;
            }
            match f.array {
                None => self.value(&f.ty, &f.name, depth)?,
                Some(len) => {
                    let n = match len {
                        Some(n) => n,
                        None => {
                            let n = self.u32(&f.name)? as usize;
                            self.align(4);
                            self.out.extend((n as u32).to_le_bytes());
                            n
                        }
                    };
                    // Every element takes at least one byte of the input.
                    if n > self.src.len() - self.pos {
                        return Err(format!(
                            "field {}: {n} elements, {} bytes left",
                            f.name,
                            self.src.len() - self.pos
                        ));
                    }
                    if f.ty == Ty::Prim(1) {
                        let b = self.take(n, &f.name)?.to_vec();
                        self.out.extend_from_slice(&b);
                    } else {
                        for _ in 0..n {
                            self.value(&f.ty, &f.name, depth)?;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn value(&mut self, ty: &Ty, field: &str, depth: usize) -> Result<(), String> {
        match ty {
            Ty::Prim(n) => {
                let b = self.take(*n, field)?.to_vec();
                self.align(*n);
                self.out.extend_from_slice(&b);
            }
            Ty::Time => {
                let b = self.take(8, field)?.to_vec();
                self.align(4);
                self.out.extend_from_slice(&b);
            }
            Ty::Str => {
                let n = self.u32(field)? as usize;
                let s = self.take(n, field)?.to_vec();
                self.align(4);
                self.out.extend(((n + 1) as u32).to_le_bytes());
                self.out.extend_from_slice(&s);
                self.out.push(0);
            }
            Ty::Msg(name) => self.message(name, depth + 1)?,
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::ros;

    const IMU_DEF: &str = "\
std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance # Row major about x, y, z axes
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
";

    const FIX_DEF: &str = "\
uint8 COVARIANCE_TYPE_UNKNOWN=0
Header header
NavSatStatus status
float64 latitude
float64 longitude
float64 altitude
float64[9] position_covariance
uint8 position_covariance_type
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
================================================================================
MSG: sensor_msgs/NavSatStatus
int8 STATUS_FIX=0
int8 status
uint16 SERVICE_GPS=1
uint16 service
";

    fn header(seq: u32, sec: u32, nsec: u32, frame: &str) -> Vec<u8> {
        let mut v = seq.to_le_bytes().to_vec();
        v.extend(sec.to_le_bytes());
        v.extend(nsec.to_le_bytes());
        v.extend((frame.len() as u32).to_le_bytes());
        v.extend(frame.as_bytes());
        v
    }

    fn f64s(v: &[f64]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    #[test]
    fn an_imu_message_decodes_as_ros2_after_transcoding() {
        let mut m = header(7, 100, 250, "/imu_link");
        m.extend(f64s(&[0.0, 0.0, 0.38268343236508984, 0.9238795325112867]));
        m.extend(f64s(&[0.01; 9]));
        m.extend(f64s(&[0.1, -0.2, 0.3]));
        m.extend(f64s(&[0.001; 9]));
        m.extend(f64s(&[0.5, 0.6, 9.81]));
        m.extend(f64s(&[0.02; 9]));
        let d = Definitions::parse("sensor_msgs/Imu", IMU_DEF).unwrap();
        let cdr = d.transcode(&m).unwrap();
        let imu = ros::decode_imu(&cdr).unwrap();
        assert_eq!(imu.stamp.0, 100_000_000_250);
        assert_eq!(imu.frame_id.as_str(), "/imu_link");
        assert!((imu.orientation.unwrap().angle() - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
        assert_eq!(imu.angular_velocity.y, -0.2);
        assert_eq!(imu.linear_acceleration.z, 9.81);
        assert_eq!(imu.linear_acceleration_covariance[(2, 2)], 0.02);
    }

    #[test]
    fn a_navsatfix_with_constants_and_a_bare_nested_type() {
        let mut m = header(1, 5, 0, "gps");
        m.push(2); // status: GBAS fix
        m.extend(1u16.to_le_bytes());
        m.extend(f64s(&[45.0, 7.5, 230.0]));
        m.extend(f64s(&[
            0.0004, 0.0, 0.0, 0.0, 0.0004, 0.0, 0.0, 0.0, 0.0016,
        ]));
        m.push(2);
        let d = Definitions::parse("sensor_msgs/NavSatFix", FIX_DEF).unwrap();
        let fix = ros::decode_nav_sat_fix(&d.transcode(&m).unwrap()).unwrap();
        assert_eq!(fix.position.lat_deg, 45.0);
        assert_eq!(fix.position.alt_m, 230.0);
        assert_eq!(fix.position_covariance[(2, 2)], 0.0016);
        assert_eq!(
            ros2_type_name("sensor_msgs/NavSatFix"),
            "sensor_msgs/msg/NavSatFix"
        );
        assert_eq!(ros2_type_name("tf/tfMessage"), "tf2_msgs/msg/TFMessage");
    }

    #[test]
    fn lies_and_cycles_are_errors() {
        let d = Definitions::parse("sensor_msgs/Imu", IMU_DEF).unwrap();
        let e = d.transcode(&header(1, 2, 3, "x")[..10]).unwrap_err();
        assert!(e.contains("field"), "{e}");
        let d = Definitions::parse("a/B", "uint8[] data\n").unwrap();
        let mut m = u32::MAX.to_le_bytes().to_vec();
        m.push(1);
        assert!(d.transcode(&m).unwrap_err().contains("elements"));
        let d = Definitions::parse("a/B", "B next\n").unwrap();
        assert!(d.transcode(&[]).unwrap_err().contains("deeper"));
    }
}
