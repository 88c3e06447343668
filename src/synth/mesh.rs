//! Triangle-mesh scenes for the virtual scanner: reading and writing PLY and OBJ meshes, and
//! nearest-hit ray casting in f64 against the exact triangles through a bounding volume
//! hierarchy of its own (binary, median split, at most [`LEAF`] triangles a leaf). The
//! hierarchy is independent of the one `mvao reference` traces, so the ground truth a mesh
//! scene gives does not share code, rounding or self-hit rules with what it judges.

use super::scene::Hit;
use crate::error::{Error, Result};
use crate::io::ply::PlyFile;
use glam::DVec3;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;

/// Most triangles in a leaf.
const LEAF: usize = 4;
/// Most triangles accepted from a file (a few million is the intended size).
pub const MAX_TRIANGLES: usize = 50_000_000;

/// A triangle mesh in world coordinates (metres, z up).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub vertices: Vec<DVec3>,
    /// Triangles: indices into `vertices`, counter-clockwise seen from the front.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// Appends a triangle by its corners.
    pub fn tri(&mut self, a: DVec3, b: DVec3, c: DVec3) {
        let k = self.vertices.len() as u32;
        self.vertices.extend([a, b, c]);
        self.triangles.push([k, k + 1, k + 2]);
    }

    /// Appends a quad `a b c d` (in order around it) as two triangles.
    pub fn quad(&mut self, a: DVec3, b: DVec3, c: DVec3, d: DVec3) {
        let k = self.vertices.len() as u32;
        self.vertices.extend([a, b, c, d]);
        self.triangles.push([k, k + 1, k + 2]);
        self.triangles.push([k, k + 2, k + 3]);
    }

    /// Appends every triangle of `other`.
    pub fn append(&mut self, other: &Mesh) {
        let k = self.vertices.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + k)));
    }

    /// Axis-aligned bounds `(min, max)` of the vertices used by triangles.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for t in &self.triangles {
            for &i in t {
                lo = lo.min(self.vertices[i as usize]);
                hi = hi.max(self.vertices[i as usize]);
            }
        }
        if lo.x > hi.x {
            return (DVec3::ZERO, DVec3::ZERO);
        }
        (lo, hi)
    }

    /// Reads a mesh from a PLY (`vertex` x y z, `face` vertex_indices) or OBJ (`v`, `f`)
    /// file, chosen by the extension. Polygons become triangle fans. Every problem is one
    /// error naming the file: no triangles, an index past the vertices, a non-finite vertex.
    pub fn read(path: &Path) -> Result<Mesh> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let (vertices, faces) = match ext.as_str() {
            "ply" => read_ply(path)?,
            "obj" => read_obj(path)?,
            _ => {
                return Err(Error::format(
                    path,
                    "mesh scenes must be .ply or .obj files",
                ))
            }
        };
        let mut triangles = Vec::with_capacity(faces.len());
        for (k, f) in faces.iter().enumerate() {
            if let Some(&bad) = f.iter().find(|&&i| i as usize >= vertices.len()) {
                return Err(Error::format(
                    path,
                    format!("face {k} refers to vertex {bad} of {}", vertices.len()),
                ));
            }
            for j in 1..f.len().saturating_sub(1) {
                triangles.push([f[0], f[j], f[j + 1]]);
            }
            if triangles.len() > MAX_TRIANGLES {
                return Err(Error::format(
                    path,
                    format!("more than {MAX_TRIANGLES} triangles"),
                ));
            }
        }
        if let Some(k) = vertices.iter().position(|v| !v.is_finite()) {
            return Err(Error::format(path, format!("vertex {k} is not finite")));
        }
        if triangles.is_empty() {
            return Err(Error::format(path, "the mesh has no triangle"));
        }
        Ok(Mesh {
            vertices,
            triangles,
        })
    }

    /// Writes the mesh as a binary little-endian PLY (float vertices, int indices), through a
    /// temporary file renamed into place.
    pub fn write_ply(&self, path: &Path) -> Result<()> {
        crate::io::atomic::write_atomic(path, |w| {
            write!(
                w,
                "ply\nformat binary_little_endian 1.0\ncomment mvao mesh scene\n\
                 element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
                 element face {}\nproperty list uchar int vertex_indices\nend_header\n",
                self.vertices.len(),
                self.triangles.len()
            )?;
            for v in &self.vertices {
                for c in v.to_array() {
                    w.write_all(&(c as f32).to_le_bytes())?;
                }
            }
            for t in &self.triangles {
                w.write_all(&[3u8])?;
                for i in t {
                    w.write_all(&(*i as i32).to_le_bytes())?;
                }
            }
            Ok(())
        })
    }

    /// Writes the mesh as a Wavefront OBJ text file (full f64 precision).
    pub fn write_obj(&self, path: &Path) -> Result<()> {
        crate::io::atomic::write_atomic(path, |w| {
            writeln!(w, "# mvao mesh scene")?;
            for v in &self.vertices {
                writeln!(w, "v {} {} {}", v.x, v.y, v.z)?;
            }
            for t in &self.triangles {
                writeln!(w, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1)?;
            }
            Ok(())
        })
    }
}

fn read_ply(path: &Path) -> Result<(Vec<DVec3>, Vec<Vec<u32>>)> {
    let ply = PlyFile::from_path(path)?;
    let xyz = ply
        .vertex_xyz()
        .ok_or_else(|| Error::format(path, "has no vertex x y z"))?;
    let faces = ply
        .list_column("face", "vertex_indices")
        .or_else(|| ply.list_column("face", "vertex_index"))
        .ok_or_else(|| Error::format(path, "has no face vertex_indices: not a mesh"))?;
    Ok((xyz.into_iter().map(DVec3::from_array).collect(), faces))
}

fn read_obj(path: &Path) -> Result<(Vec<DVec3>, Vec<Vec<u32>>)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let (mut verts, mut faces) = (Vec::new(), Vec::new());
    for (ln, line) in BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| Error::io(path, e))?;
        let bad = |what: &str| Error::format(path, format!("line {}: {what}", ln + 1));
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f64> = it.take(3).map_while(|s| s.parse().ok()).collect();
                if c.len() != 3 {
                    return Err(bad("a vertex needs three numbers"));
                }
                verts.push(DVec3::new(c[0], c[1], c[2]));
            }
            Some("f") => {
                let mut f = Vec::new();
                for tok in it {
                    let first = tok.split('/').next().unwrap_or("");
                    let i: i64 = first.parse().map_err(|_| bad("unreadable face index"))?;
                    // OBJ indices start at 1; negative ones count back from the last vertex.
                    let k = if i > 0 { i - 1 } else { verts.len() as i64 + i };
                    if k < 0 || k >= verts.len() as i64 {
                        return Err(bad(&format!("face index {i} out of range")));
                    }
                    f.push(k as u32);
                }
                if f.len() < 3 {
                    return Err(bad("a face needs three vertices"));
                }
                faces.push(f);
            }
            _ => {}
        }
    }
    Ok((verts, faces))
}

/// A triangle prepared for ray tests.
#[derive(Debug, Clone, Copy)]
struct Tri {
    v0: DVec3,
    e1: DVec3,
    e2: DVec3,
    /// Index in the mesh.
    index: u32,
}

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: DVec3,
    hi: DVec3,
    /// Leaf: first triangle; interior: index of the second child (the first follows).
    at: u32,
    /// Triangles in a leaf; 0 for an interior node.
    count: u32,
}

/// A mesh ready for nearest-hit queries (degenerate triangles left out).
#[derive(Debug, Clone)]
pub struct MeshScene {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    normals: Vec<DVec3>,
    extent: f64,
}

impl MeshScene {
    /// Builds the hierarchy over `mesh`'s non-degenerate triangles.
    pub fn new(mesh: &Mesh) -> MeshScene {
        let normals: Vec<DVec3> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
                (b - a).cross(c - a).normalize_or_zero()
            })
            .collect();
        let mut tris: Vec<Tri> = mesh
            .triangles
            .iter()
            .enumerate()
            .filter(|(k, _)| normals[*k] != DVec3::ZERO)
            .map(|(k, t)| {
                let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
                Tri {
                    v0: a,
                    e1: b - a,
                    e2: c - a,
                    index: k as u32,
                }
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * tris.len() / LEAF + 1);
        if !tris.is_empty() {
            let n = tris.len();
            build(&mut tris, 0, n, &mut nodes);
        }
        let (lo, hi) = mesh.bounds();
        MeshScene {
            nodes,
            tris,
            normals,
            extent: (hi - lo).max_element().max(f64::MIN_POSITIVE),
        }
    }

    /// Triangles in the hierarchy (degenerate ones included).
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Largest side of the mesh's bounding box.
    pub fn extent(&self) -> f64 {
        self.extent
    }

    /// Unit normal of mesh triangle `k` (counter-clockwise front; zero if degenerate).
    pub fn normal(&self, k: usize) -> DVec3 {
        self.normals.get(k).copied().unwrap_or(DVec3::ZERO)
    }

    /// Nearest hit of `origin + t·dir` with `t ∈ (t_min, t_max)`, skipping triangle `skip`
    /// (the one a ray starts from). The normal is the face normal, not turned to the ray.
    pub fn intersect_skip(
        &self,
        origin: DVec3,
        dir: DVec3,
        t_min: f64,
        t_max: f64,
        skip: u32,
    ) -> Option<Hit> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv = dir.recip();
        let mut best: Option<(f64, u32)> = None;
        let mut limit = t_max;
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if slab(node.lo, node.hi, origin, inv, limit).is_none() {
                continue;
            }
            if node.count > 0 {
                let first = node.at as usize;
                for tr in &self.tris[first..first + node.count as usize] {
                    if tr.index == skip {
                        continue;
                    }
                    if let Some(t) = hit(tr, origin, dir, t_min, limit) {
                        limit = t;
                        best = Some((t, tr.index));
                    }
                }
                continue;
            }
            let (a, b) = (stack[sp] + 1, node.at);
            let ta = slab(
                self.nodes[a as usize].lo,
                self.nodes[a as usize].hi,
                origin,
                inv,
                limit,
            );
            let tb = slab(
                self.nodes[b as usize].lo,
                self.nodes[b as usize].hi,
                origin,
                inv,
                limit,
            );
            // Push the farther child first so the nearer one is searched first.
            let mut push = |k: u32| {
                if sp < stack.len() {
                    stack[sp] = k;
                    sp += 1;
                }
            };
            match (ta, tb) {
                (Some(x), Some(y)) if x <= y => {
                    push(b);
                    push(a);
                }
                (Some(_), Some(_)) => {
                    push(a);
                    push(b);
                }
                (Some(_), None) => push(a),
                (None, Some(_)) => push(b),
                (None, None) => {}
            }
        }
        best.map(|(t, k)| Hit {
            t,
            normal: self.normals[k as usize],
            prim: k as usize,
        })
    }
}

impl MeshScene {
    /// The point of the mesh nearest to `p` within `max_dist`, with the index of its
    /// triangle: where a measured point lies on a reconstructed surface.
    pub fn nearest(&self, p: DVec3, max_dist: f64) -> Option<(DVec3, u32)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best: Option<(DVec3, u32)> = None;
        let mut best_d2 = max_dist * max_dist;
        let mut stack = [0u32; 64];
        let mut sp = 1usize;
        let box_d2 = |n: &Node| ((n.lo - p).max(p - n.hi).max(DVec3::ZERO)).length_squared();
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if box_d2(node) > best_d2 {
                continue;
            }
            if node.count > 0 {
                let first = node.at as usize;
                for tr in &self.tris[first..first + node.count as usize] {
                    let q = closest_on_triangle(p, tr.v0, tr.v0 + tr.e1, tr.v0 + tr.e2);
                    let d2 = q.distance_squared(p);
                    if d2 < best_d2 {
                        best_d2 = d2;
                        best = Some((q, tr.index));
                    }
                }
                continue;
            }
            for k in [node.at, stack[sp] + 1] {
                if sp < stack.len() {
                    stack[sp] = k;
                    sp += 1;
                }
            }
        }
        best
    }
}

/// The point of triangle `abc` nearest to `p` (Ericson, Real-Time Collision Detection 5.1.5).
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> DVec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Entry distance of the ray into the box if it meets it before `limit`.
#[inline]
fn slab(lo: DVec3, hi: DVec3, o: DVec3, inv: DVec3, limit: f64) -> Option<f64> {
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    // NaN (0·∞ on a face plane) is ignored by max/min, which keeps such rays inside.
    let t0 = a.min(b).max_element().max(0.0);
    let t1 = a.max(b).min_element().min(limit);
    (t0 <= t1).then_some(t0)
}

/// Möller–Trumbore in f64, either side.
#[inline]
fn hit(tr: &Tri, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<f64> {
    let p = d.cross(tr.e2);
    let det = tr.e1.dot(p);
    if det == 0.0 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tr.v0;
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(tr.e1);
    let v = d.dot(q) * inv;
    if !(v >= 0.0 && u + v <= 1.0) {
        return None;
    }
    let t = tr.e2.dot(q) * inv;
    (t > t_min && t < t_max).then_some(t)
}

fn tri_bounds(t: &Tri) -> (DVec3, DVec3) {
    let (b, c) = (t.v0 + t.e1, t.v0 + t.e2);
    (t.v0.min(b).min(c), t.v0.max(b).max(c))
}

/// Builds the subtree of `tris[first..end]` into `nodes` (depth first, first child next).
fn build(tris: &mut [Tri], first: usize, end: usize, nodes: &mut Vec<Node>) {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    let (mut clo, mut chi) = (lo, hi);
    for t in &tris[first..end] {
        let (a, b) = tri_bounds(t);
        lo = lo.min(a);
        hi = hi.max(b);
        let c = (a + b) * 0.5;
        clo = clo.min(c);
        chi = chi.max(c);
    }
    let me = nodes.len();
    nodes.push(Node {
        lo,
        hi,
        at: first as u32,
        count: (end - first) as u32,
    });
    let span = chi - clo;
    if end - first <= LEAF || span.max_element() <= 0.0 {
        return;
    }
    let axis = if span.x >= span.y && span.x >= span.z {
        0
    } else if span.y >= span.z {
        1
    } else {
        2
    };
    let mid = (first + end) / 2;
    let key = |t: &Tri| {
        let (a, b) = tri_bounds(t);
        (a + b)[axis]
    };
    tris[first..end].select_nth_unstable_by(mid - first, |x, y| key(x).total_cmp(&key(y)));
    build(tris, first, mid, nodes);
    let second = nodes.len() as u32;
    build(tris, mid, end, nodes);
    nodes[me].at = second;
    nodes[me].count = 0;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_mesh(n: usize) -> Mesh {
        // A wavy heightfield of 2·n² triangles over [0, 1]².
        let mut m = Mesh::default();
        let h = |x: f64, y: f64| 0.1 * (7.0 * x).sin() * (5.0 * y).cos();
        let step = 1.0 / n as f64;
        for i in 0..n {
            for j in 0..n {
                let (x0, y0) = (i as f64 * step, j as f64 * step);
                let (x1, y1) = (x0 + step, y0 + step);
                let p = |x: f64, y: f64| DVec3::new(x, y, h(x, y));
                m.quad(p(x0, y0), p(x1, y0), p(x1, y1), p(x0, y1));
            }
        }
        m
    }

    #[test]
    fn bvh_matches_brute_force() {
        let m = grid_mesh(24);
        let sc = MeshScene::new(&m);
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let o = DVec3::new(rnd() * 1.4 - 0.2, rnd() * 1.4 - 0.2, 0.5 * rnd() - 0.25);
            let d = DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize();
            let fast = sc.intersect_skip(o, d, 0.0, 10.0, u32::MAX);
            let mut slow: Option<(f64, usize)> = None;
            for (k, t) in m.triangles.iter().enumerate() {
                let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                let tr = Tri {
                    v0: a,
                    e1: b - a,
                    e2: c - a,
                    index: k as u32,
                };
                if let Some(t) = hit(&tr, o, d, 0.0, slow.map_or(10.0, |s| s.0)) {
                    slow = Some((t, k));
                }
            }
            assert_eq!(fast.map(|h| h.t), slow.map(|s| s.0));
        }
    }

    #[test]
    fn nearest_point_matches_brute_force() {
        let m = grid_mesh(12);
        let sc = MeshScene::new(&m);
        for k in 0..300 {
            let f = k as f64;
            let p = DVec3::new(
                (f * 0.37).fract() * 1.2 - 0.1,
                (f * 0.61).fract(),
                (f * 0.13).sin() * 0.3,
            );
            let (q, _) = sc.nearest(p, 10.0).unwrap();
            let best = m
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| m.vertices[i as usize]);
                    closest_on_triangle(p, a, b, c).distance(p)
                })
                .fold(f64::INFINITY, f64::min);
            assert!((q.distance(p) - best).abs() < 1e-12, "{k}");
        }
        assert!(sc.nearest(DVec3::new(0.5, 0.5, 5.0), 1.0).is_none());
    }

    #[test]
    fn obj_and_ply_round_trip_and_bad_files() {
        let dir = tempfile::tempdir().unwrap();
        let m = grid_mesh(3);
        let (obj, ply) = (dir.path().join("m.obj"), dir.path().join("m.ply"));
        m.write_obj(&obj).unwrap();
        m.write_ply(&ply).unwrap();
        assert_eq!(Mesh::read(&obj).unwrap(), m);
        let back = Mesh::read(&ply).unwrap();
        assert_eq!(back.triangles, m.triangles);
        for (a, b) in back.vertices.iter().zip(&m.vertices) {
            assert!(a.distance(*b) < 1e-6);
        }
        let bad = dir.path().join("bad.obj");
        std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap();
        let e = Mesh::read(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.obj") && e.contains("line 3"), "{e}");
        let empty = dir.path().join("empty.obj");
        std::fs::write(&empty, "v 0 0 0\n").unwrap();
        let e = Mesh::read(&empty).unwrap_err().to_string();
        assert!(e.contains("empty.obj") && e.contains("no triangle"), "{e}");
        let e = Mesh::read(&dir.path().join("m.stl"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("m.stl"), "{e}");
    }
}
