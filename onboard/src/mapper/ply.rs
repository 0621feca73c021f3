//! Binary little-endian PLY: the map cloud and the mesh, written and read back.
//!
//! The reader understands any binary little-endian PLY with scalar and list properties
//! of the standard types (enough for our own files and for most tools' output); ASCII and
//! big-endian files are refused with a message that says so.

use super::{MapperError, PointCloud, TriangleMesh};
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::Path;

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlyType {
    /// `char` / `int8`.
    I8,
    /// `uchar` / `uint8`.
    U8,
    /// `short` / `int16`.
    I16,
    /// `ushort` / `uint16`.
    U16,
    /// `int` / `int32`.
    I32,
    /// `uint` / `uint32`.
    U32,
    /// `float` / `float32`.
    F32,
    /// `double` / `float64`.
    F64,
}

impl PlyType {
    fn parse(s: &str) -> Option<PlyType> {
        Some(match s {
            "char" | "int8" => PlyType::I8,
            "uchar" | "uint8" => PlyType::U8,
            "short" | "int16" => PlyType::I16,
            "ushort" | "uint16" => PlyType::U16,
            "int" | "int32" => PlyType::I32,
            "uint" | "uint32" => PlyType::U32,
            "float" | "float32" => PlyType::F32,
            "double" | "float64" => PlyType::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            PlyType::I8 | PlyType::U8 => 1,
            PlyType::I16 | PlyType::U16 => 2,
            PlyType::I32 | PlyType::U32 | PlyType::F32 => 4,
            PlyType::F64 => 8,
        }
    }
    fn read(self, b: &[u8]) -> f64 {
        match self {
            PlyType::I8 => f64::from(b[0] as i8),
            PlyType::U8 => f64::from(b[0]),
            PlyType::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            PlyType::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            PlyType::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            PlyType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            PlyType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            PlyType::F64 => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
        }
    }
}

/// The values of one property of an element.
#[derive(Clone, Debug, PartialEq)]
pub enum PlyColumn {
    /// A scalar per row (every type widened to `f64` exactly).
    Scalar(Vec<f64>),
    /// A list per row (indices).
    List(Vec<Vec<u32>>),
}

/// One element (`vertex`, `face`, ...) of a PLY file.
#[derive(Clone, Debug, PartialEq)]
pub struct PlyElement {
    /// Element name.
    pub name: String,
    /// Number of rows.
    pub count: usize,
    /// Property names and values, in file order.
    pub properties: Vec<(String, PlyColumn)>,
}

impl PlyElement {
    fn scalar(&self, name: &str) -> Option<&[f64]> {
        self.properties.iter().find_map(|(n, c)| match c {
            PlyColumn::Scalar(v) if n == name => Some(v.as_slice()),
            _ => None,
        })
    }
    fn list(&self, name: &str) -> Option<&[Vec<u32>]> {
        self.properties.iter().find_map(|(n, c)| match c {
            PlyColumn::List(v) if n == name => Some(v.as_slice()),
            _ => None,
        })
    }
}

fn ply_err(
    path: &Path,
    field: impl Into<String>,
    expected: impl Into<String>,
    found: impl Into<String>,
) -> MapperError {
    MapperError::Ply {
        path: path.to_path_buf(),
        field: field.into(),
        expected: expected.into(),
        found: found.into(),
    }
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> MapperError + '_ {
    move |source| MapperError::Io {
        path: path.to_path_buf(),
        source,
    }
}

enum PropSpec {
    Scalar(String, PlyType),
    List(String, PlyType, PlyType),
}

/// Reads every element of a binary little-endian PLY file.
pub fn read_ply(path: &Path) -> Result<Vec<PlyElement>, MapperError> {
    let file = std::fs::File::open(path).map_err(io_err(path))?;
    let mut r = BufReader::new(file);
    let mut line = String::new();
    let mut header: Vec<(String, usize, Vec<PropSpec>)> = Vec::new();
    let mut first = true;
    loop {
        line.clear();
        if r.read_line(&mut line).map_err(io_err(path))? == 0 {
            return Err(ply_err(
                path,
                "header",
                "a line `end_header`",
                "end of file",
            ));
        }
        let words: Vec<&str> = line.split_whitespace().collect();
        if first {
            if words != ["ply"] {
                return Err(ply_err(path, "magic", "`ply`", line.trim()));
            }
            first = false;
            continue;
        }
        match words.as_slice() {
            ["format", "binary_little_endian", "1.0"] => {}
            ["format", f, ..] => {
                return Err(ply_err(path, "format", "binary_little_endian 1.0", *f));
            }
            ["comment", ..] | ["obj_info", ..] | [] => {}
            ["element", name, count] => {
                let count = count
                    .parse()
                    .map_err(|_| ply_err(path, format!("element {name}"), "a row count", *count))?;
                header.push((name.to_string(), count, Vec::new()));
            }
            ["property", "list", ct, it, name] => {
                let (Some(ct), Some(it)) = (PlyType::parse(ct), PlyType::parse(it)) else {
                    return Err(ply_err(
                        path,
                        format!("property {name}"),
                        "list of standard types",
                        line.trim(),
                    ));
                };
                let Some(el) = header.last_mut() else {
                    return Err(ply_err(
                        path,
                        "property",
                        "an element before it",
                        line.trim(),
                    ));
                };
                el.2.push(PropSpec::List(name.to_string(), ct, it));
            }
            ["property", ty, name] => {
                let Some(ty) = PlyType::parse(ty) else {
                    return Err(ply_err(
                        path,
                        format!("property {name}"),
                        "a standard scalar type",
                        *ty,
                    ));
                };
                let Some(el) = header.last_mut() else {
                    return Err(ply_err(
                        path,
                        "property",
                        "an element before it",
                        line.trim(),
                    ));
                };
                el.2.push(PropSpec::Scalar(name.to_string(), ty));
            }
            ["end_header"] => break,
            _ => return Err(ply_err(path, "header", "a PLY header line", line.trim())),
        }
    }
    let mut out = Vec::with_capacity(header.len());
    let mut buf = [0u8; 8];
    for (name, count, props) in header {
        let mut cols: Vec<PlyColumn> = props
            .iter()
            .map(|p| match p {
                PropSpec::Scalar(..) => PlyColumn::Scalar(Vec::with_capacity(count)),
                PropSpec::List(..) => PlyColumn::List(Vec::with_capacity(count)),
            })
            .collect();
        for row in 0..count {
            for (p, col) in props.iter().zip(cols.iter_mut()) {
                let short = |_| ply_err(path, format!("{name}[{row}]"), "more data", "end of file");
                match (p, col) {
                    (PropSpec::Scalar(_, ty), PlyColumn::Scalar(v)) => {
                        r.read_exact(&mut buf[..ty.size()]).map_err(short)?;
                        v.push(ty.read(&buf));
                    }
                    (PropSpec::List(_, ct, it), PlyColumn::List(v)) => {
                        r.read_exact(&mut buf[..ct.size()]).map_err(short)?;
                        let n = ct.read(&buf) as usize;
                        let mut items = Vec::with_capacity(n);
                        for _ in 0..n {
                            r.read_exact(&mut buf[..it.size()]).map_err(short)?;
                            items.push(it.read(&buf) as u32);
                        }
                        v.push(items);
                    }
                    _ => unreachable!("columns are made from the specs"),
                }
            }
        }
        out.push(PlyElement {
            name,
            count,
            properties: props
                .iter()
                .map(|p| match p {
                    PropSpec::Scalar(n, _) | PropSpec::List(n, ..) => n.clone(),
                })
                .zip(cols)
                .collect(),
        });
    }
    Ok(out)
}

fn element<'a>(
    els: &'a [PlyElement],
    path: &Path,
    name: &str,
) -> Result<&'a PlyElement, MapperError> {
    els.iter()
        .find(|e| e.name == name)
        .ok_or_else(|| ply_err(path, format!("element {name}"), "present", "absent"))
}

fn column<'a>(el: &'a PlyElement, path: &Path, name: &str) -> Result<&'a [f64], MapperError> {
    el.scalar(name).ok_or_else(|| {
        ply_err(
            path,
            format!("{}.{name}", el.name),
            "a scalar property",
            "absent",
        )
    })
}

fn triples_f32(
    el: &PlyElement,
    path: &Path,
    names: [&str; 3],
) -> Result<Vec<[f32; 3]>, MapperError> {
    let [a, b, c] = [
        column(el, path, names[0])?,
        column(el, path, names[1])?,
        column(el, path, names[2])?,
    ];
    Ok((0..el.count)
        .map(|i| [a[i] as f32, b[i] as f32, c[i] as f32])
        .collect())
}

fn triples_u8(el: &PlyElement, path: &Path) -> Result<Vec<[u8; 3]>, MapperError> {
    let [a, b, c] = [
        column(el, path, "red")?,
        column(el, path, "green")?,
        column(el, path, "blue")?,
    ];
    Ok((0..el.count)
        .map(|i| [a[i] as u8, b[i] as u8, c[i] as u8])
        .collect())
}

fn create(path: &Path) -> Result<BufWriter<std::fs::File>, MapperError> {
    Ok(BufWriter::with_capacity(
        1 << 20,
        std::fs::File::create(path).map_err(io_err(path))?,
    ))
}

/// Writes the map cloud: `x y z` float, `red green blue` uchar, `nx ny nz` float, `grvi`
/// float, `elevation` float per vertex. Missing normals, GRVI or elevation are written
/// as zeros.
pub fn write_cloud(cloud: &PointCloud, path: &Path) -> Result<(), MapperError> {
    write_cloud_colored(cloud, &cloud.colors, path)
}

/// Points of a cloud serialised per write.
const CLOUD_POINTS_PER_WRITE: usize = 1 << 16;

/// [`write_cloud`] with `colors` in place of the cloud's own (a point without one gets
/// black), so a recoloured copy of the cloud need not be made. Written in slices of
/// [`CLOUD_POINTS_PER_WRITE`] points through one reused buffer.
pub fn write_cloud_colored(
    cloud: &PointCloud,
    colors: &[[u8; 3]],
    path: &Path,
) -> Result<(), MapperError> {
    let mut w = create(path)?;
    let n = cloud.positions.len();
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment vinebench map (world frame, ENU, metres)\n\
         element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property float grvi\nproperty float elevation\nend_header\n"
    );
    w.write_all(header.as_bytes()).map_err(io_err(path))?;
    let mut buf = Vec::with_capacity(CLOUD_POINTS_PER_WRITE * 35);
    for from in (0..n).step_by(CLOUD_POINTS_PER_WRITE) {
        buf.clear();
        for i in from..(from + CLOUD_POINTS_PER_WRITE).min(n) {
            for c in cloud.positions[i] {
                buf.extend_from_slice(&c.to_le_bytes());
            }
            buf.extend_from_slice(&colors.get(i).copied().unwrap_or([0; 3]));
            for c in cloud.normals.get(i).copied().unwrap_or([0.0; 3]) {
                buf.extend_from_slice(&c.to_le_bytes());
            }
            buf.extend_from_slice(&cloud.grvi.get(i).copied().unwrap_or(0.0).to_le_bytes());
            buf.extend_from_slice(&cloud.elevation.get(i).copied().unwrap_or(0.0).to_le_bytes());
        }
        w.write_all(&buf).map_err(io_err(path))?;
    }
    w.flush().map_err(io_err(path))
}

/// Reads a cloud written by [`write_cloud`] (or any PLY with `x y z`; colour, normals,
/// `grvi` and `elevation` are read where present).
pub fn read_cloud(path: &Path) -> Result<PointCloud, MapperError> {
    let els = read_ply(path)?;
    let v = element(&els, path, "vertex")?;
    Ok(PointCloud {
        positions: triples_f32(v, path, ["x", "y", "z"])?,
        colors: if v.scalar("red").is_some() {
            triples_u8(v, path)?
        } else {
            Vec::new()
        },
        normals: if v.scalar("nx").is_some() {
            triples_f32(v, path, ["nx", "ny", "nz"])?
        } else {
            Vec::new()
        },
        grvi: v
            .scalar("grvi")
            .map(|g| g.iter().map(|x| *x as f32).collect())
            .unwrap_or_default(),
        elevation: v
            .scalar("elevation")
            .map(|g| g.iter().map(|x| *x as f32).collect())
            .unwrap_or_default(),
    })
}

/// Writes a mesh: vertices `x y z nx ny nz` float and `red green blue` uchar, faces as
/// `uchar`-counted `int` index lists.
pub fn write_mesh(mesh: &TriangleMesh, path: &Path) -> Result<(), MapperError> {
    let mut w = create(path)?;
    let (nv, nf) = (mesh.vertices.len(), mesh.triangles.len());
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment vinebench mesh (Ball-Pivoting)\n\
         element vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face {nf}\nproperty list uchar int vertex_indices\nend_header\n"
    );
    let mut buf = Vec::with_capacity(header.len() + nv * 27 + nf * 13);
    buf.extend_from_slice(header.as_bytes());
    for i in 0..nv {
        for c in mesh.vertices[i] {
            buf.extend_from_slice(&c.to_le_bytes());
        }
        for c in mesh.normals.get(i).copied().unwrap_or([0.0; 3]) {
            buf.extend_from_slice(&c.to_le_bytes());
        }
        buf.extend_from_slice(&mesh.colors.get(i).copied().unwrap_or([200; 3]));
    }
    for t in &mesh.triangles {
        buf.push(3);
        for i in t {
            buf.extend_from_slice(&(*i as i32).to_le_bytes());
        }
    }
    w.write_all(&buf).map_err(io_err(path))?;
    w.flush().map_err(io_err(path))
}

/// Reads a triangle mesh (faces with other than 3 vertices are refused).
pub fn read_mesh(path: &Path) -> Result<TriangleMesh, MapperError> {
    let els = read_ply(path)?;
    let v = element(&els, path, "vertex")?;
    let f = element(&els, path, "face")?;
    let faces = f
        .list("vertex_indices")
        .or_else(|| f.list("vertex_index"))
        .ok_or_else(|| ply_err(path, "face.vertex_indices", "a list property", "absent"))?;
    let mut triangles = Vec::with_capacity(faces.len());
    for (i, face) in faces.iter().enumerate() {
        match face.as_slice() {
            &[a, b, c] if (a.max(b).max(c) as usize) < v.count => triangles.push([a, b, c]),
            _ => {
                return Err(ply_err(
                    path,
                    format!("face[{i}]"),
                    format!("3 indices below {}", v.count),
                    format!("{face:?}"),
                ));
            }
        }
    }
    Ok(TriangleMesh {
        vertices: triples_f32(v, path, ["x", "y", "z"])?,
        normals: if v.scalar("nx").is_some() {
            triples_f32(v, path, ["nx", "ny", "nz"])?
        } else {
            Vec::new()
        },
        colors: if v.scalar("red").is_some() {
            triples_u8(v, path)?
        } else {
            Vec::new()
        },
        triangles,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A cloud written with other colours equals the cloud recoloured and written, byte
    /// for byte, across several write slices (and with too few colours: black), and reads
    /// back.
    #[test]
    fn a_cloud_written_with_other_colours_equals_the_recoloured_cloud() {
        let n = 2 * CLOUD_POINTS_PER_WRITE + 17;
        let f = |i: usize, k: usize| (i * 3 + k) as f32 * 0.001 - 50.0;
        let cloud = PointCloud {
            positions: (0..n).map(|i| [f(i, 0), f(i, 1), f(i, 2)]).collect(),
            colors: (0..n).map(|i| [(i % 251) as u8, 3, 9]).collect(),
            normals: (0..n).map(|i| [f(i, 2), 0.5, -0.25]).collect(),
            grvi: (0..n).map(|i| f(i, 1) * 0.01).collect(),
            elevation: (0..n).map(|i| f(i, 0) * 0.1).collect(),
        };
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.ply"), dir.path().join("b.ply"));
        for len in [n, n - 100] {
            let colours: Vec<[u8; 3]> = (0..len).map(|i| [7, (i % 256) as u8, 200]).collect();
            let mut recoloured = cloud.clone();
            recoloured.colors = colours.clone();
            write_cloud_colored(&cloud, &colours, &a).unwrap();
            write_cloud(&recoloured, &b).unwrap();
            assert!(
                std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
                "{len} colours"
            );
        }
        let back = read_cloud(&b).unwrap();
        assert_eq!(back.positions, cloud.positions);
        assert_eq!(back.colors[n - 1], [0; 3]);
        assert_eq!(back.colors[0], [7, 0, 200]);
    }
}
