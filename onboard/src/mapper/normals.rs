//! Point normals by principal component analysis of the k nearest neighbours (k-d tree:
//! kiddo), oriented towards the sensor that saw each point.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use std::num::NonZero;

/// Unit normals of `points`: the eigenvector of the smallest eigenvalue of the covariance
/// of each point's `k` nearest neighbours (the point included), flipped to face its
/// `viewpoint` (the camera centre that saw it). Where the neighbourhood is degenerate
/// (fewer than 3 points) the normal is the unit vector towards the viewpoint.
///
/// The k-d tree holds the `f32` points as they are (the neighbour search only compares
/// distances); the covariance is accumulated in `f64` about the neighbourhood's mean.
pub fn estimate_normals(points: &[[f32; 3]], viewpoints: &[[f32; 3]], k: usize) -> Vec<[f32; 3]> {
    if points.is_empty() {
        return Vec::new();
    }
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(points);
    let at = |i: u64| {
        let p = points[i as usize];
        Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
    };
    let k = NonZero::new(k.max(3)).unwrap_or(NonZero::<usize>::MIN);
    points
        .par_iter()
        .zip(viewpoints.par_iter())
        .map(|(p, vp)| {
            let pv = Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            let to_view = Vector3::new(f64::from(vp[0]), f64::from(vp[1]), f64::from(vp[2])) - pv;
            let nn = tree.nearest_n::<SquaredEuclidean>(p, k);
            let fallback = to_view.try_normalize(1e-12).unwrap_or_else(Vector3::z);
            let normal = if nn.len() < 3 {
                fallback
            } else {
                let mut mean = Vector3::zeros();
                for q in &nn {
                    mean += at(q.item);
                }
                mean /= nn.len() as f64;
                let mut cov = Matrix3::zeros();
                for q in &nn {
                    let d = at(q.item) - mean;
                    cov += d * d.transpose();
                }
                let eig = SymmetricEigen::new(cov);
                let (mut imin, mut vmin) = (0, f64::INFINITY);
                for (i, v) in eig.eigenvalues.iter().enumerate() {
                    if *v < vmin {
                        (imin, vmin) = (i, *v);
                    }
                }
                let n = eig.eigenvectors.column(imin).into_owned();
                match n.try_normalize(1e-12) {
                    Some(n) if n.dot(&to_view) < 0.0 => -n,
                    Some(n) => n,
                    None => fallback,
                }
            };
            [normal.x as f32, normal.y as f32, normal.z as f32]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_of_a_tilted_plane_face_the_viewpoint() {
        // Plane z = 0.5·x, seen from above.
        let pts: Vec<[f32; 3]> = (0..400u16)
            .map(|i| {
                let (x, y) = (f32::from(i % 20) * 0.01, f32::from(i / 20) * 0.01);
                [x, y, 0.5 * x]
            })
            .collect();
        let vps = vec![[0.1f32, 0.1, 2.0]; pts.len()];
        let n = estimate_normals(&pts, &vps, 10);
        let expected = Vector3::new(-0.5, 0.0, 1.0).normalize();
        for v in &n {
            let v = Vector3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
            assert!(v.dot(&expected) > 0.9999, "{v:?}");
        }
    }
}
