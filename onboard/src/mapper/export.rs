//! Exports for simulators: Wavefront OBJ with vertex colours, a Gazebo model folder
//! (`model.config`, `model.sdf` whose visual and collision both use the mesh) and an
//! MJCF snippet for MuJoCo.

use super::{MapperError, TriangleMesh};
use rayon::prelude::*;
use std::io::{BufWriter, Write};
use std::path::Path;

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> MapperError + '_ {
    move |source| MapperError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn write_text(path: &Path, text: &str) -> Result<(), MapperError> {
    std::fs::write(path, text).map_err(io_err(path))
}

/// Reads a Wavefront OBJ triangle mesh: every object and group merged into one mesh,
/// polygons split into fans, points and lines left out, normals and texture coordinates
/// ignored; vertex colours (`v x y z r g b` in 0..1, as [`write_obj`] writes them) when
/// the file has them (a file where only some vertices have one is refused). Vertices
/// come in the order faces first use them (per object), so vertex indices can differ
/// from the file's; unused vertices are dropped.
pub fn read_obj(path: &Path) -> Result<TriangleMesh, MapperError> {
    let file = std::fs::File::open(path).map_err(io_err(path))?;
    let opts = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials (`mtllib`) are not read: the mesh is drawn with its vertex colours.
    let (models, _) = tobj::load_obj_buf(&mut std::io::BufReader::new(file), &opts, |_| {
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| MapperError::Obj {
        path: path.to_path_buf(),
        problem: e.to_string(),
    })?;
    let mut mesh = TriangleMesh::default();
    let mut coloured = true;
    for m in &models {
        let base = u32::try_from(mesh.vertices.len()).map_err(|_| MapperError::Obj {
            path: path.to_path_buf(),
            problem: "more than 2^32 vertices".into(),
        })?;
        let (p, c) = (&m.mesh.positions, &m.mesh.vertex_color);
        mesh.vertices
            .extend(p.chunks_exact(3).map(|v| [v[0], v[1], v[2]]));
        coloured &= c.len() == p.len();
        if coloured {
            mesh.colors
                .extend(c.chunks_exact(3).map(|c| {
                    [c[0], c[1], c[2]].map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
                }));
        }
        mesh.triangles.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }
    if !coloured {
        mesh.colors.clear();
    }
    Ok(mesh)
}

/// Writes `mesh` as Wavefront OBJ: `v x y z r g b` (colour in 0..1, the extension
/// MeshLab, Open3D and Blender read), `vn` normals when present, and 1-based faces.
pub fn write_obj(mesh: &TriangleMesh, path: &Path) -> Result<(), MapperError> {
    write_obj_to(mesh, &[path])
}

/// Lines of an OBJ formatted per parallel task.
const OBJ_LINES_PER_CHUNK: usize = 16_384;

/// [`write_obj`] to each of `paths`, the same bytes in each. The text is formatted once,
/// in chunks of lines on rayon's threads, and each round of chunks is written in order,
/// so memory stays at a few megabytes whatever the mesh.
pub fn write_obj_to(mesh: &TriangleMesh, paths: &[&Path]) -> Result<(), MapperError> {
    let mut files = paths
        .iter()
        .map(|p| {
            let file = std::fs::File::create(p).map_err(io_err(p))?;
            Ok((BufWriter::with_capacity(1 << 20, file), *p))
        })
        .collect::<Result<Vec<_>, MapperError>>()?;
    let mut write_all = |bytes: &[u8]| {
        files
            .iter_mut()
            .try_for_each(|(w, p)| w.write_all(bytes).map_err(io_err(p)))
    };
    write_all(b"# vinebench mesh (Ball-Pivoting), world frame (ENU), metres\n")?;
    // A colour channel is one of 256 values: its text `{:.4}` of `c / 255` once each.
    let channel: Vec<String> = (0..=255u8)
        .map(|c| format!("{:.4}", f32::from(c) / 255.0))
        .collect();
    let nv = mesh.vertices.len();
    // Normals are written when every vertex has one.
    let nn = if mesh.normals.len() == nv { nv } else { 0 };
    let lines = nv + nn + mesh.triangles.len();
    let chunks = lines.div_ceil(OBJ_LINES_PER_CHUNK);
    let per_round = 4 * rayon::current_num_threads().max(1);
    for round in (0..chunks).step_by(per_round) {
        let texts: Vec<String> = (round..(round + per_round).min(chunks))
            .into_par_iter()
            .map(|chunk| {
                let from = chunk * OBJ_LINES_PER_CHUNK;
                let to = (from + OBJ_LINES_PER_CHUNK).min(lines);
                let mut s = String::with_capacity(64 * (to - from));
                for line in from..to {
                    obj_line(mesh, &channel, nn, line, &mut s);
                }
                s
            })
            .collect();
        for t in &texts {
            write_all(t.as_bytes())?;
        }
    }
    files
        .iter_mut()
        .try_for_each(|(w, p)| w.flush().map_err(io_err(p)))
}

/// Appends line `line` of the OBJ body (the vertices, then `nn` normals: all or none,
/// then the faces) to `s`; `channel[c]` is the text of colour channel value `c`.
fn obj_line(mesh: &TriangleMesh, channel: &[String], nn: usize, line: usize, s: &mut String) {
    use std::fmt::Write as _;
    let nv = mesh.vertices.len();
    // Writing to a `String` cannot fail.
    let _ = if line < nv {
        let v = mesh.vertices[line];
        let c = mesh.colors.get(line).copied().unwrap_or([200; 3]);
        let [r, g, b] = c.map(|x| channel[usize::from(x)].as_str());
        writeln!(s, "v {} {} {} {r} {g} {b}", v[0], v[1], v[2])
    } else if line < nv + nn {
        let n = mesh.normals[line - nv];
        writeln!(s, "vn {} {} {}", n[0], n[1], n[2])
    } else {
        let [a, b, c] = mesh.triangles[line - nv - nn].map(|i| u64::from(i) + 1);
        if nn > 0 {
            writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}")
        } else {
            writeln!(s, "f {a} {b} {c}")
        }
    };
}

/// Escapes text for XML content and attributes.
fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The SDF (1.9) of a static model whose single link has the mesh as visual and as
/// collision. `mesh_uri` is what Gazebo resolves (`model://<name>/meshes/mesh.obj`).
pub fn model_sdf(name: &str, mesh_uri: &str) -> String {
    let (name, uri) = (xml_escape(name), xml_escape(mesh_uri));
    format!(
        r#"<?xml version="1.0"?>
<sdf version="1.9">
  <model name="{name}">
    <static>true</static>
    <link name="map">
      <collision name="collision">
        <geometry>
          <mesh>
            <uri>{uri}</uri>
          </mesh>
        </geometry>
      </collision>
      <visual name="visual">
        <geometry>
          <mesh>
            <uri>{uri}</uri>
          </mesh>
        </geometry>
      </visual>
    </link>
  </model>
</sdf>
"#
    )
}

/// The `model.config` of a Gazebo model folder.
pub fn model_config(name: &str) -> String {
    let name = xml_escape(name);
    format!(
        r#"<?xml version="1.0"?>
<model>
  <name>{name}</name>
  <version>1.0</version>
  <sdf version="1.9">model.sdf</sdf>
  <author>
    <name>vinebench</name>
  </author>
  <description>Vineyard map reconstructed by the vinebench mapper (RGB-D, Ball-Pivoting mesh), world frame ENU.</description>
</model>
"#
    )
}

/// An MJCF document with the mesh as an asset and a static geom (MuJoCo collides with
/// a mesh's convex hull; the geom is for display and coarse contact).
pub fn mjcf(name: &str, mesh_file: &str) -> String {
    let (name, file) = (xml_escape(name), xml_escape(mesh_file));
    format!(
        r#"<mujoco model="{name}">
  <asset>
    <mesh name="{name}_mesh" file="{file}"/>
  </asset>
  <worldbody>
    <geom name="{name}" type="mesh" mesh="{name}_mesh" contype="1" conaffinity="1" rgba="0.6 0.6 0.6 1"/>
  </worldbody>
</mujoco>
"#
    )
}

/// Writes a Gazebo model folder `<dir>/<name>/` with `model.config`, `model.sdf` and
/// `meshes/mesh.obj`; returns the folder.
pub fn write_gazebo_model(
    mesh: &TriangleMesh,
    dir: &Path,
    name: &str,
) -> Result<std::path::PathBuf, MapperError> {
    let (model, obj) = gazebo_model_folder(dir, name)?;
    write_obj(mesh, &obj)?;
    Ok(model)
}

/// The Gazebo model folder `<dir>/<name>/` of [`write_gazebo_model`] without its mesh:
/// `model.config`, `model.sdf` and the `meshes/` folder. Returns the folder and the path
/// its `mesh.obj` must be written to.
pub fn gazebo_model_folder(
    dir: &Path,
    name: &str,
) -> Result<(std::path::PathBuf, std::path::PathBuf), MapperError> {
    let model = dir.join(name);
    let meshes = model.join("meshes");
    std::fs::create_dir_all(&meshes).map_err(io_err(&meshes))?;
    write_text(&model.join("model.config"), &model_config(name))?;
    write_text(
        &model.join("model.sdf"),
        &model_sdf(name, &format!("model://{name}/meshes/mesh.obj")),
    )?;
    Ok((model, meshes.join("mesh.obj")))
}

/// Writes `<dir>/<name>.mjcf.xml` referencing `mesh_file` (relative to `dir`).
pub fn write_mjcf(dir: &Path, name: &str, mesh_file: &str) -> Result<(), MapperError> {
    write_text(
        &dir.join(format!("{name}.mjcf.xml")),
        &mjcf(name, mesh_file),
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn read_text(text: &str) -> Result<TriangleMesh, MapperError> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.obj");
        std::fs::write(&path, text).unwrap();
        read_obj(&path)
    }

    #[test]
    fn obj_objects_merge_and_polygons_split_into_fans() {
        // Two coloured objects: a quad (1-based, then a negative = relative index), and a
        // triangle.
        let text = "o quad\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 1 1 0 0 0 1\nv 0 1 0 1 1 1\n\
                    f 1 2 3 -1\no tri\nv 5 5 5 0 0 0\nv 6 5 5 0.5 0.5 0.5\nv 5 6 5 1 0 1\n\
                    f 5 6 7\n";
        let m = read_text(text).unwrap();
        assert_eq!(m.triangles.len(), 3);
        let corners = |t: [u32; 3]| t.map(|i| (m.vertices[i as usize], m.colors[i as usize]));
        let (red, green, blue, white) = ([255, 0, 0], [0, 255, 0], [0, 0, 255], [255; 3]);
        // The quad's fan from its first corner, then the triangle.
        assert_eq!(
            corners(m.triangles[0]),
            [
                ([0.0, 0.0, 0.0], red),
                ([1.0, 0.0, 0.0], green),
                ([1.0, 1.0, 0.0], blue)
            ]
        );
        assert_eq!(
            corners(m.triangles[1]),
            [
                ([0.0, 0.0, 0.0], red),
                ([1.0, 1.0, 0.0], blue),
                ([0.0, 1.0, 0.0], white)
            ]
        );
        assert_eq!(
            corners(m.triangles[2]),
            [
                ([5.0, 5.0, 5.0], [0; 3]),
                ([6.0, 5.0, 5.0], [128; 3]),
                ([5.0, 6.0, 5.0], [255, 0, 255])
            ]
        );
        // Without colours: none.
        let plain = read_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        assert_eq!(plain.triangles, [[0, 1, 2]]);
        assert!(plain.colors.is_empty());
    }

    #[test]
    fn a_bad_obj_is_refused_naming_the_file() {
        let e = read_text("v 0 0 zero\nf 1 1 1\n").unwrap_err().to_string();
        assert!(e.contains("m.obj") && e.contains("OBJ"), "{e}");
        // A face past the vertices, and colours on some vertices only.
        for text in [
            "v 0 0 0\nv 1 0 0\nf 1 2 3\n",
            "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        ] {
            let e = read_text(text).unwrap_err().to_string();
            assert!(e.contains("m.obj") && e.contains("OBJ"), "{text}: {e}");
        }
        let e = read_obj(Path::new("/no/such/dir/m.obj"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/no/such/dir/m.obj"), "{e}");
    }

    /// A mesh of `n` vertices with coordinates of every magnitude and sign, every colour
    /// value, and faces over them.
    fn mesh(n: usize, normals: bool, colours: bool) -> TriangleMesh {
        let mut x = 0x9E37_79B9_u32;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        let mut coord = || {
            let r = next();
            let scale = [1e-7f32, 1e-3, 0.5, 8.0, 120.0, 3.0e5][(r % 6) as usize];
            (f32::from((r >> 8) as u16) / 65535.0 - 0.5) * scale
        };
        let vertices: Vec<[f32; 3]> = (0..n).map(|_| [coord(), coord(), coord()]).collect();
        TriangleMesh {
            normals: if normals {
                (0..n).map(|_| [coord(), coord(), coord()]).collect()
            } else {
                Vec::new()
            },
            colors: if colours {
                (0..n)
                    .map(|i| [(i % 256) as u8, (i * 7 % 256) as u8, 255])
                    .collect()
            } else {
                Vec::new()
            },
            triangles: (0..n.saturating_sub(2) as u32)
                .map(|i| [i, i + 1, i + 2])
                .collect(),
            vertices,
        }
    }

    /// The OBJ as a line-by-line `writeln!` of each element (the format as written before
    /// it was formatted in parallel chunks).
    fn obj_reference(m: &TriangleMesh) -> String {
        use std::fmt::Write as _;
        let mut s = String::from("# vinebench mesh (Ball-Pivoting), world frame (ENU), metres\n");
        for (i, v) in m.vertices.iter().enumerate() {
            let c = m.colors.get(i).copied().unwrap_or([200; 3]);
            let [r, g, b] = c.map(|x| f32::from(x) / 255.0);
            writeln!(s, "v {} {} {} {r:.4} {g:.4} {b:.4}", v[0], v[1], v[2]).unwrap();
        }
        let with_normals = m.normals.len() == m.vertices.len() && !m.normals.is_empty();
        if with_normals {
            for n in &m.normals {
                writeln!(s, "vn {} {} {}", n[0], n[1], n[2]).unwrap();
            }
        }
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| i + 1);
            if with_normals {
                writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}").unwrap();
            } else {
                writeln!(s, "f {a} {b} {c}").unwrap();
            }
        }
        s
    }

    /// The chunked, parallel OBJ writer gives the line-by-line text byte for byte, in
    /// every copy: meshes across several chunks (with and without normals and colours),
    /// one short of a chunk, and empty.
    #[test]
    fn the_obj_is_the_line_by_line_text_in_every_copy() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.obj"), dir.path().join("b.obj"));
        for (n, normals, colours) in [
            (20_000, true, true),
            (20_000, false, true),
            (20_000, true, false),
            (OBJ_LINES_PER_CHUNK - 1, false, false),
            (0, true, true),
        ] {
            let m = mesh(n, normals, colours);
            write_obj_to(&m, &[&a, &b]).unwrap();
            let expected = obj_reference(&m);
            for p in [&a, &b] {
                let text = std::fs::read_to_string(p).unwrap();
                assert!(
                    text == expected,
                    "{n} vertices, normals {normals}: {p:?} differs"
                );
            }
        }
        // Every colour channel's text is what `{:.4}` of c/255 gives.
        let m = mesh(256, false, true);
        write_obj(&m, &a).unwrap();
        assert_eq!(std::fs::read_to_string(&a).unwrap(), obj_reference(&m));
        // A folder that cannot be written is named.
        let e = write_obj_to(&m, &[&a, Path::new("/no/such/dir/m.obj")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("/no/such/dir/m.obj"), "{e}");
    }
}
