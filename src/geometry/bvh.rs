//! A bounding-volume hierarchy over triangles (median split), with the two queries the checks
//! need: the triangles within a distance of a point, and the triangles a line segment crosses.

use crate::geometry::triangle_distance;
use glam::DVec3;

/// Leaf size. Why: a leaf's triangles are tested exactly; 4 keeps boxes tight.
const BVH_LEAF: usize = 4;

/// The hierarchy; it stores triangle indices only, the caller passes the mesh to each query.
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

#[derive(Clone, Copy, Debug)]
pub struct Node {
    pub lo: DVec3,
    pub hi: DVec3,
    /// Leaf: first index into `order` and count; inner: left and right child (count = 0).
    pub a: u32,
    pub b: u32,
    pub count: u32,
}

fn tri(pos: &[DVec3], faces: &[[u32; 3]], f: u32) -> [DVec3; 3] {
    faces[f as usize].map(|v| pos[v as usize])
}

impl Bvh {
    pub fn build(pos: &[DVec3], faces: &[[u32; 3]]) -> Bvh {
        let boxes: Vec<(DVec3, DVec3)> = (0..faces.len() as u32)
            .map(|f| {
                let p = tri(pos, faces, f);
                (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]))
            })
            .collect();
        let centers: Vec<DVec3> = boxes.iter().map(|(lo, hi)| 0.5 * (*lo + *hi)).collect();
        let mut order: Vec<u32> = (0..faces.len() as u32).collect();
        let mut nodes = Vec::new();
        fn rec(nodes: &mut Vec<Node>, order: &mut [u32], first: usize, centers: &[DVec3], boxes: &[(DVec3, DVec3)]) -> u32 {
            let mut lo = DVec3::splat(f64::INFINITY);
            let mut hi = DVec3::splat(f64::NEG_INFINITY);
            for &f in order.iter() {
                lo = lo.min(boxes[f as usize].0);
                hi = hi.max(boxes[f as usize].1);
            }
            let id = nodes.len() as u32;
            nodes.push(Node { lo, hi, a: first as u32, b: 0, count: order.len() as u32 });
            if order.len() <= BVH_LEAF {
                return id;
            }
            let ext = hi - lo;
            let axis = if ext.x >= ext.y && ext.x >= ext.z { 0 } else if ext.y >= ext.z { 1 } else { 2 };
            let mid = order.len() / 2;
            order.select_nth_unstable_by(mid, |&p, &q| {
                centers[p as usize][axis].total_cmp(&centers[q as usize][axis]).then(p.cmp(&q))
            });
            let (l, r) = order.split_at_mut(mid);
            let left = rec(nodes, l, first, centers, boxes);
            let right = rec(nodes, r, first + mid, centers, boxes);
            nodes[id as usize] = Node { lo, hi, a: left, b: right, count: 0 };
            id
        }
        if !order.is_empty() {
            rec(&mut nodes, &mut order, 0, &centers, &boxes);
        }
        Bvh { nodes, order }
    }

    /// The nodes, root first (the GPU projection walks them).
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }
    /// Triangle indices in leaf order (a leaf covers `order[a .. a + count]`).
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    fn leaf(&self, node: &Node) -> &[u32] {
        &self.order[node.a as usize..(node.a + node.count) as usize]
    }

    /// Calls `f` with every triangle of the leaves whose box lies within `limit` of `x` (a
    /// superset of [`Bvh::near`]'s, unsorted, in the tree's order): for a caller with a sharper
    /// test of its own.
    pub fn visit_within(&self, x: DVec3, limit: f64, mut f: impl FnMut(u32)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = self.nodes[n as usize];
            if x.clamp(node.lo, node.hi).distance(x) > limit {
                continue;
            }
            if node.count > 0 {
                self.leaf(&node).iter().for_each(|&t| f(t));
            } else {
                stack.push(node.a);
                stack.push(node.b);
            }
        }
    }

    /// Triangles whose distance to `x` is at most `limit`, ascending by (distance, index).
    pub fn near(&self, pos: &[DVec3], faces: &[[u32; 3]], x: DVec3, limit: f64, out: &mut Vec<(f64, u32)>) {
        out.clear();
        self.visit_within(x, limit, |f| {
            let d = triangle_distance(x, &tri(pos, faces, f));
            if d <= limit {
                out.push((d, f));
            }
        });
        out.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    }

    /// Parameters t ∈ [t0, t1] at which the line `o + t·dir` crosses a triangle, with the
    /// triangle index (Möller–Trumbore; a crossing exactly on a shared edge is reported by
    /// both triangles, the caller merges equal t).
    pub fn crossings(&self, pos: &[DVec3], faces: &[[u32; 3]], o: DVec3, dir: DVec3, t0: f64, t1: f64, out: &mut Vec<(f64, u32)>) {
        out.clear();
        if self.nodes.is_empty() {
            return;
        }
        let inv = DVec3::ONE / dir;
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            let node = self.nodes[n as usize];
            // Slab test of the segment against the box.
            let ta = (node.lo - o) * inv;
            let tb = (node.hi - o) * inv;
            let tmin = ta.min(tb);
            let tmax = ta.max(tb);
            let enter = [tmin.x, tmin.y, tmin.z, t0].iter().copied().filter(|v| !v.is_nan()).fold(f64::NEG_INFINITY, f64::max);
            let exit = [tmax.x, tmax.y, tmax.z, t1].iter().copied().filter(|v| !v.is_nan()).fold(f64::INFINITY, f64::min);
            if enter > exit {
                continue;
            }
            if node.count > 0 {
                for &f in self.leaf(&node) {
                    let p = tri(pos, faces, f);
                    if let Some(t) = line_triangle(o, dir, &p) {
                        if t >= t0 && t <= t1 {
                            out.push((t, f));
                        }
                    }
                }
            } else {
                stack.push(node.a);
                stack.push(node.b);
            }
        }
        out.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    }
}

/// Where the line `o + t·dir` crosses triangle `p` (edges included), as t.
pub fn line_triangle(o: DVec3, dir: DVec3, p: &[DVec3; 3]) -> Option<f64> {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    let h = dir.cross(e2);
    let a = e1.dot(h);
    if a.abs() <= 1e-300 {
        return None;
    }
    let f = 1.0 / a;
    let s = o - p[0];
    let u = f * s.dot(h);
    let eps = crate::geometry::BARY_EPS;
    if u < -eps || u > 1.0 + eps {
        return None;
    }
    let q = s.cross(e1);
    let v = f * dir.dot(q);
    if v < -eps || u + v > 1.0 + eps {
        return None;
    }
    Some(f * e2.dot(q))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn near_and_crossings_match_brute_force() {
        // A 10 x 10 grid of unit squares in z = 0, two triangles each.
        let mut pos = Vec::new();
        for j in 0..11 {
            for i in 0..11 {
                pos.push(DVec3::new(i as f64, j as f64, 0.0));
            }
        }
        let mut faces = Vec::new();
        for j in 0..10u32 {
            for i in 0..10u32 {
                let a = j * 11 + i;
                faces.push([a, a + 1, a + 12]);
                faces.push([a, a + 12, a + 11]);
            }
        }
        let bvh = Bvh::build(&pos, &faces);
        let x = DVec3::new(3.3, 4.6, 0.5);
        let mut out = Vec::new();
        bvh.near(&pos, &faces, x, 0.9, &mut out);
        let brute: Vec<u32> =
            (0..faces.len() as u32).filter(|&f| triangle_distance(x, &tri(&pos, &faces, f)) <= 0.9).collect();
        let mut got: Vec<u32> = out.iter().map(|e| e.1).collect();
        got.sort();
        assert_eq!(got, brute);
        // A vertical line through the interior of one triangle crosses it once, at z = 0.
        bvh.crossings(&pos, &faces, DVec3::new(3.3, 4.6, 1.0), DVec3::new(0.0, 0.0, -1.0), -5.0, 5.0, &mut out);
        assert_eq!(out.len(), 1);
        assert!((out[0].0 - 1.0).abs() < 1e-12);
        // Outside the segment range: nothing.
        bvh.crossings(&pos, &faces, DVec3::new(3.3, 4.6, 1.0), DVec3::new(0.0, 0.0, -1.0), -0.5, 0.5, &mut out);
        assert!(out.is_empty());
    }
}
