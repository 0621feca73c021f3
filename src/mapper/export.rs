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
