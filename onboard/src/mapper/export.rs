//! Exports for simulators: Wavefront OBJ with vertex colours, a Gazebo model folder
//! (`model.config`, `model.sdf` whose visual and collision both use the mesh) and an
//! MJCF snippet for MuJoCo.

use super::{MapperError, TriangleMesh};
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
    let file = std::fs::File::create(path).map_err(io_err(path))?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    let e = io_err(path);
    writeln!(
        w,
        "# vinebench mesh (Ball-Pivoting), world frame (ENU), metres"
    )
    .map_err(&e)?;
    for (i, v) in mesh.vertices.iter().enumerate() {
        let c = mesh.colors.get(i).copied().unwrap_or([200; 3]);
        writeln!(
            w,
            "v {} {} {} {:.4} {:.4} {:.4}",
            v[0],
            v[1],
            v[2],
            f32::from(c[0]) / 255.0,
            f32::from(c[1]) / 255.0,
            f32::from(c[2]) / 255.0
        )
        .map_err(&e)?;
    }
    let with_normals = mesh.normals.len() == mesh.vertices.len() && !mesh.normals.is_empty();
    if with_normals {
        for n in &mesh.normals {
            writeln!(w, "vn {} {} {}", n[0], n[1], n[2]).map_err(&e)?;
        }
    }
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| i + 1);
        if with_normals {
            writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}").map_err(&e)?;
        } else {
            writeln!(w, "f {a} {b} {c}").map_err(&e)?;
        }
    }
    w.flush().map_err(&e)
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
    let model = dir.join(name);
    let meshes = model.join("meshes");
    std::fs::create_dir_all(&meshes).map_err(io_err(&meshes))?;
    write_obj(mesh, &meshes.join("mesh.obj"))?;
    write_text(&model.join("model.config"), &model_config(name))?;
    write_text(
        &model.join("model.sdf"),
        &model_sdf(name, &format!("model://{name}/meshes/mesh.obj")),
    )?;
    Ok(model)
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
}
