//! Lanelet neighbours and whether a vehicle may change between them, Lanelet2 style.
//!
//! Two lanelets are neighbours when they run in the same direction and share a bound: the left
//! bound of one is the right bound of the other, as the same way or as the same node sequence in
//! driving direction. Whether a change across that bound is allowed follows its line type where
//! the map has one: Lanelet2's `subtype` (`dashed` allows both ways, `solid`/`solid_solid`
//! forbid, `solid_dashed`/`dashed_solid` allow one way, read along the way as drawn) or the SML
//! maps' `line_type` (`interior` allows, `exterior` forbids). Any other `type` (a line of unknown
//! pattern, a curbstone) forbids; a `virtual` line (no paint) or an untagged bound allows.
//! Lanelets a vehicle may not drive (crosswalks, ...) have no neighbours.

use std::collections::BTreeMap;

use super::lanelet::{LaneletId, LaneletMap, MapWay};

/// The neighbours of one lanelet and whether a change to each is allowed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Neighbours {
    /// The lanelet beside it on the left (same direction, sharing its left bound).
    pub left: Option<LaneletId>,
    /// The lanelet beside it on the right (same direction, sharing its right bound).
    pub right: Option<LaneletId>,
    /// Whether a vehicle may change into `left` (false when there is none).
    pub change_left: bool,
    /// Whether a vehicle may change into `right` (false when there is none).
    pub change_right: bool,
}

/// Which crossings a line allows, read along the way as drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Crossing {
    Both,
    None,
    /// From the way's left side to its right side only (Lanelet2 `dashed_solid`).
    ToRight,
    /// From the way's right side to its left side only (Lanelet2 `solid_dashed`).
    ToLeft,
}

fn crossing(way: &MapWay) -> Crossing {
    let tag = |k: &str| way.tags.get(k).map(String::as_str);
    match (tag("subtype"), tag("line_type")) {
        (Some("dashed"), _) | (_, Some("interior")) => Crossing::Both,
        (Some("solid" | "solid_solid"), _) | (_, Some("exterior")) => Crossing::None,
        (Some("dashed_solid"), _) => Crossing::ToRight,
        (Some("solid_dashed"), _) => Crossing::ToLeft,
        // A painted line of unknown pattern, a kerb, a wall: as Lanelet2, no change.
        _ if tag("type").is_some_and(|t| t != "virtual") => Crossing::None,
        // No paint (`virtual`, inside intersections) or no tags at all.
        _ => Crossing::Both,
    }
}

impl LaneletMap {
    /// Neighbours of every lanelet, in [`LaneletMap::lanelets`] order. O(N log N) in lanelets.
    pub fn neighbours(&self) -> Vec<Neighbours> {
        // Right bounds in driving direction -> lanelets (the candidates for a left neighbour).
        let mut by_right: BTreeMap<&[i64], Vec<usize>> = BTreeMap::new();
        for (i, l) in self.lanelets.iter().enumerate() {
            if l.routable {
                by_right.entry(&l.right_nodes).or_default().push(i);
            }
        }
        let mut out = vec![Neighbours::default(); self.lanelets.len()];
        for (i, l) in self.lanelets.iter().enumerate() {
            if !l.routable {
                continue;
            }
            let Some(candidates) = by_right.get(l.left_nodes.as_slice()) else { continue };
            // Several lanelets on one bound only where a map draws overlapping lanes: take the
            // first in id order so the answer does not depend on anything else.
            let Some(&j) = candidates.iter().find(|&&j| j != i) else { continue };
            let other = &self.lanelets[j];
            out[i].left = Some(other.id);
            out[j].right = Some(l.id);
            // The shared bound, as `l`'s left way (and `other`'s right way, when a different one
            // with the same nodes: the stricter of the two rules).
            let (to_left, to_right) = [l.left_way, other.right_way]
                .iter()
                .filter_map(|w| self.ways.get(w))
                .map(|w| {
                    // `l` lies on the right of the line in driving direction; when the way runs
                    // against the driving direction, its sides swap.
                    let along = w.nodes.first() == l.left_nodes.first() && w.nodes.last() == l.left_nodes.last();
                    let c = crossing(w);
                    let right_to_left = matches!(c, Crossing::Both | Crossing::ToLeft);
                    let left_to_right = matches!(c, Crossing::Both | Crossing::ToRight);
                    if along { (right_to_left, left_to_right) } else { (left_to_right, right_to_left) }
                })
                .fold((true, true), |(a, b), (c, d)| (a && c, b && d));
            out[i].change_left = to_left;
            out[j].change_right = to_right;
        }
        out
    }

    /// Neighbours of one lanelet (computes the whole table; keep [`LaneletMap::neighbours`] when
    /// asking about many).
    pub fn neighbours_of(&self, id: LaneletId) -> Option<Neighbours> {
        self.lanelet_index(id).map(|i| self.neighbours()[i])
    }
}
