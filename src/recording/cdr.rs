//! CDR (XCDR1, little-endian) as ROS 2 serializes messages: a 4-byte encapsulation
//! header `00 01 00 00`, then the fields in declaration order, each primitive aligned to
//! its own size (at most 8) relative to the first byte after the header. Strings are a
//! `u32` length that counts the terminating NUL, the bytes and the NUL; sequences are a
//! `u32` element count and the elements; fixed-size arrays are the elements alone.

use thiserror::Error;
use vinebench_msgs::Nanos;

/// The encapsulation header of little-endian plain CDR (`CDR_LE`).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A CDR payload that does not decode as the expected type.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
pub enum CdrError {
    /// The payload ends inside a field.
    #[error("field `{field}`: payload ends at byte {at}, {needed} more byte(s) expected")]
    Truncated {
        /// The field being read.
        field: &'static str,
        /// Offset (after the encapsulation header) where the field starts.
        at: usize,
        /// Bytes missing.
        needed: usize,
    },
    /// The encapsulation header is not little-endian CDR.
    #[error("encapsulation header {found:02x?}: expected little-endian CDR (00 01 00 00)")]
    Encapsulation {
        /// The first bytes of the payload.
        found: Vec<u8>,
    },
    /// A field holds a value the type does not allow.
    #[error("field `{field}`: {problem}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// What is wrong and what was expected.
        problem: String,
    },
}

/// Serializes fields into a CDR payload (header included).
#[derive(Debug)]
pub struct CdrWriter<'a> {
    buf: &'a mut Vec<u8>,
    /// Index of the first byte after the encapsulation header.
    origin: usize,
}

impl<'a> CdrWriter<'a> {
    /// Clears `buf` and writes the encapsulation header; fields follow.
    pub fn new(buf: &'a mut Vec<u8>) -> CdrWriter<'a> {
        buf.clear();
        buf.extend_from_slice(&CDR_LE_HEADER);
        CdrWriter { buf, origin: 4 }
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - self.origin;
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    /// `uint8` / `byte` / `char`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// `int8`.
    pub fn i8(&mut self, v: i8) {
        self.buf.push(v as u8);
    }
    /// `bool`.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }
    /// `uint16`.
    pub fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `int16`.
    pub fn i16(&mut self, v: i16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// A fixed-size `float64[N]` array.
    pub fn f64s(&mut self, v: &[f64]) {
        for x in v {
            self.f64(*x);
        }
    }
    /// `string`.
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    /// A sequence length (`uint32`), before the elements.
    pub fn seq_len(&mut self, n: usize) {
        self.u32(n as u32);
    }
    /// `uint8[]`: length and bytes.
    pub fn bytes(&mut self, v: &[u8]) {
        self.seq_len(v.len());
        self.buf.extend_from_slice(v);
    }
    /// `builtin_interfaces/Time` of a stamp (`sec` floors towards −∞, `nanosec` in
    /// `[0, 1e9)`).
    pub fn time(&mut self, t: Nanos) {
        self.i32(t.0.div_euclid(1_000_000_000) as i32);
        self.u32(t.0.rem_euclid(1_000_000_000) as u32);
    }
}

/// Reads fields from a CDR payload.
#[derive(Debug)]
pub struct CdrReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header; fields follow.
    pub fn new(payload: &'a [u8]) -> Result<CdrReader<'a>, CdrError> {
        match payload.get(..4) {
            Some([0x00, 0x01, _, _]) => Ok(CdrReader {
                data: &payload[4..],
                pos: 0,
            }),
            _ => Err(CdrError::Encapsulation {
                found: payload.iter().take(4).copied().collect(),
            }),
        }
    }

    /// Bytes left after the current position.
    pub fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }

    fn take(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], CdrError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        match end {
            Some(end) => {
                let s = &self.data[self.pos..end];
                self.pos = end;
                Ok(s)
            }
            None => Err(CdrError::Truncated {
                field,
                at: self.pos,
                needed: n - self.remaining(),
            }),
        }
    }

    fn align(&mut self, n: usize, field: &'static str) -> Result<(), CdrError> {
        let pad = (n - self.pos % n) % n;
        self.take(pad, field).map(|_| ())
    }

    fn array<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], CdrError> {
        self.align(N, field)?;
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, field)?);
        Ok(a)
    }

    /// `uint8`.
    pub fn u8(&mut self, field: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(1, field)?[0])
    }
    /// `int8`.
    pub fn i8(&mut self, field: &'static str) -> Result<i8, CdrError> {
        Ok(self.take(1, field)?[0] as i8)
    }
    /// `bool` (any non-zero byte is true).
    pub fn bool(&mut self, field: &'static str) -> Result<bool, CdrError> {
        Ok(self.take(1, field)?[0] != 0)
    }
    /// `uint16`.
    pub fn u16(&mut self, field: &'static str) -> Result<u16, CdrError> {
        self.array(field).map(u16::from_le_bytes)
    }
    /// `int16`.
    pub fn i16(&mut self, field: &'static str) -> Result<i16, CdrError> {
        self.array(field).map(i16::from_le_bytes)
    }
    /// `uint32`.
    pub fn u32(&mut self, field: &'static str) -> Result<u32, CdrError> {
        self.array(field).map(u32::from_le_bytes)
    }
    /// `int32`.
    pub fn i32(&mut self, field: &'static str) -> Result<i32, CdrError> {
        self.array(field).map(i32::from_le_bytes)
    }
    /// `float64`.
    pub fn f64(&mut self, field: &'static str) -> Result<f64, CdrError> {
        self.array(field).map(f64::from_le_bytes)
    }
    /// A fixed-size `float64[N]` array.
    pub fn f64s<const N: usize>(&mut self, field: &'static str) -> Result<[f64; N], CdrError> {
        let mut a = [0.0; N];
        for x in &mut a {
            *x = self.f64(field)?;
        }
        Ok(a)
    }
    /// A sequence length, checked against the bytes left (each element takes at least
    /// `min_elem_bytes`), so a corrupt length cannot ask for a huge allocation.
    pub fn seq_len(
        &mut self,
        field: &'static str,
        min_elem_bytes: usize,
    ) -> Result<usize, CdrError> {
        let n = self.u32(field)? as usize;
        if n.saturating_mul(min_elem_bytes) > self.remaining() {
            return Err(CdrError::Truncated {
                field,
                at: self.pos,
                needed: n * min_elem_bytes - self.remaining(),
            });
        }
        Ok(n)
    }
    /// `uint8[]`.
    pub fn bytes(&mut self, field: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.seq_len(field, 1)?;
        self.take(n, field)
    }
    /// `string` (UTF-8; the terminating NUL is dropped).
    pub fn string(&mut self, field: &'static str) -> Result<&'a str, CdrError> {
        let n = self.seq_len(field, 1)?;
        let raw = self.take(n, field)?;
        let raw = raw.strip_suffix(&[0]).unwrap_or(raw);
        std::str::from_utf8(raw).map_err(|e| CdrError::Invalid {
            field,
            problem: format!("not UTF-8 ({e})"),
        })
    }
    /// `builtin_interfaces/Time` as a stamp.
    pub fn time(&mut self, field: &'static str) -> Result<Nanos, CdrError> {
        let sec = self.i32(field)?;
        let nanosec = self.u32(field)?;
        if nanosec >= 1_000_000_000 {
            return Err(CdrError::Invalid {
                field,
                problem: format!("nanosec {nanosec}: expected < 1000000000"),
            });
        }
        Ok(Nanos(i64::from(sec) * 1_000_000_000 + i64::from(nanosec)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_is_relative_to_the_payload() {
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        w.u8(7);
        w.f64(1.0);
        w.string("ab");
        w.u16(3);
        assert_eq!(
            buf,
            [
                0, 1, 0, 0, // header
                7, 0, 0, 0, 0, 0, 0, 0, // u8 + 7 bytes of padding to offset 8
                0, 0, 0, 0, 0, 0, 0xf0, 0x3f, // 1.0
                3, 0, 0, 0, b'a', b'b', 0, // "ab" with its NUL
                0, 3, 0, // pad to 2, then 3u16
            ]
        );
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.f64("b").unwrap(), 1.0);
        assert_eq!(r.string("c").unwrap(), "ab");
        assert_eq!(r.u16("d").unwrap(), 3);
        assert!(matches!(
            r.u8("e"),
            Err(CdrError::Truncated { field: "e", .. })
        ));
    }

    #[test]
    fn negative_stamps_floor() {
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        w.time(Nanos(-1));
        assert_eq!(&buf[4..], &[0xff, 0xff, 0xff, 0xff, 0xff, 0xc9, 0x9a, 0x3b]);
        assert_eq!(CdrReader::new(&buf).unwrap().time("t").unwrap(), Nanos(-1));
    }

    #[test]
    fn huge_sequence_lengths_are_refused() {
        let buf = [0, 1, 0, 0, 0xff, 0xff, 0xff, 0x7f];
        let mut r = CdrReader::new(&buf).unwrap();
        assert!(matches!(r.bytes("data"), Err(CdrError::Truncated { .. })));
        assert!(CdrReader::new(&[0, 0, 0, 0]).is_err());
    }
}
