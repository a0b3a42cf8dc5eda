//! Collapsing the binary tree into the wide one: each wide node takes a
//! binary node's two children and, while it has fewer than [`WIDTH`]
//! (eight), replaces the interior child of largest surface area by its two
//! children (the child most likely to be entered is the one opened, as in
//! Embree's BVH8 builder). Leaves stay as they are, so the leaf order, and with it the
//! primitive numbering [`Bvh::take_leaf_order`](super::Bvh::take_leaf_order)
//! hands out, is the binary tree's.

use super::{Node, Pair, Ref, WIDTH};
use crate::geometry::Aabb;

/// The wide tree of the binary tree `pairs` rooted at `root`: its nodes
/// (the root first, then depth first) and the root's new reference.
pub(super) fn collapse(pairs: &[Pair], root: Ref) -> (Vec<Node>, Ref) {
    if root.count > 0 {
        return (Vec::new(), root);
    }
    // A binary tree of p interior nodes collapses into at most p wide ones
    // (usually about p/(WIDTH − 1)); reserve for 2·p/WIDTH (the bytes of p/2
    // nodes of four) and shrink at the end.
    let mut nodes = Vec::with_capacity(2 * pairs.len() / WIDTH + 1);
    let r = node(pairs, root.first as usize, &mut nodes);
    nodes.shrink_to_fit();
    (nodes, r)
}

/// Makes the wide node for binary node `pairs[i]` and its subtree.
fn node(pairs: &[Pair], i: usize, out: &mut Vec<Node>) -> Ref {
    let p = &pairs[i];
    let mut kids: [(Aabb, Ref); WIDTH] = [(Aabb::EMPTY, Ref::NONE); WIDTH];
    kids[0] = (p.child_box(0), p.child[0]);
    kids[1] = (p.child_box(1), p.child[1]);
    let mut n = 2;
    while n < WIDTH {
        // The interior child of largest area (the first of equals).
        let mut best: Option<usize> = None;
        for (k, (b, r)) in kids[..n].iter().enumerate() {
            if r.count == 0 && best.is_none_or(|j| b.half_area() > kids[j].0.half_area()) {
                best = Some(k);
            }
        }
        let Some(k) = best else { break };
        let q = &pairs[kids[k].1.first as usize];
        // Its children take its slot and the next free one, in order.
        kids.copy_within(k + 1..n, k + 2);
        kids[k] = (q.child_box(0), q.child[0]);
        kids[k + 1] = (q.child_box(1), q.child[1]);
        n += 1;
    }
    let index = out.len();
    out.push(Node::EMPTY);
    let mut wide = Node::EMPTY;
    for (k, &(b, r)) in kids[..n].iter().enumerate() {
        let r = if r.count == 0 {
            node(pairs, r.first as usize, out)
        } else {
            r
        };
        wide.set(k, b, r);
    }
    out[index] = wide;
    Ref {
        first: index as u32,
        count: 0,
    }
}
