//! The routing graph: directed lanelets and which follows which (by shared bound end nodes),
//! built from plain lanelet data so the lanelet layer needs nothing of routing.

use std::collections::BTreeMap;

use glam::DVec2;

/// Directed lanelets as a graph: state `2 * index + reversed`; reversed states exist only for
/// `one_way=no` lanelets, and no state exists for lanelets a vehicle may not drive.
#[derive(Debug, Clone, Default)]
pub(crate) struct RoutingGraph {
    pub(crate) successors: Vec<Vec<u32>>,
    /// Node id -> states whose right bound (in their driving direction) contains the node: the
    /// 2015 rule (seed §3.3.2) for which lanelets a start or end node selects.
    pub(crate) node_states: BTreeMap<i64, Vec<u32>>,
    /// Node id -> states whose left bound (in their driving direction) contains the node: the
    /// fallback for nodes on no right bound (Lanelet2 maps tag the left marking too).
    pub(crate) node_left_states: BTreeMap<i64, Vec<u32>>,
    /// Centre-line length of every state [m] (indexed like `successors`): the searches read
    /// these compact arrays, not the lanelets (a cache miss each on a big map).
    pub(crate) lengths: Vec<f64>,
    /// Where every state's centre line ends in its driving direction (A*'s heuristic).
    pub(crate) ends: Vec<DVec2>,
}

/// What the graph needs of one lanelet (in map order).
#[derive(Debug, Clone, Copy)]
pub(crate) struct GraphLanelet<'a> {
    /// Whether a vehicle may drive it.
    pub routable: bool,
    /// Whether it may be driven against its direction too (`one_way=no`).
    pub bidirectional: bool,
    /// Node ids of the right bound, in driving direction.
    pub right_nodes: &'a [i64],
    /// Node ids of the left bound, in driving direction.
    pub left_nodes: &'a [i64],
    /// Centre-line length [m].
    pub length: f64,
    /// First and last centre-line point [m].
    pub centre_ends: (DVec2, DVec2),
}

impl RoutingGraph {
    pub(crate) fn new(lanelets: &[GraphLanelet<'_>]) -> RoutingGraph {
        RoutingGraph::build(lanelets, None)
    }

    /// The graph of one-way lanelets whose successors are given (by index into `lanelets`), as
    /// CommonRoad files list them, instead of found by shared bound nodes.
    pub(crate) fn with_successors(lanelets: &[GraphLanelet<'_>], successors: &[Vec<usize>]) -> RoutingGraph {
        RoutingGraph::build(lanelets, Some(successors))
    }

    fn build(lanelets: &[GraphLanelet<'_>], explicit: Option<&[Vec<usize>]>) -> RoutingGraph {
        let n = lanelets.len();
        let mut valid = vec![false; 2 * n];
        let mut by_start: BTreeMap<(i64, i64), Vec<u32>> = BTreeMap::new();
        let mut node_states: BTreeMap<i64, Vec<u32>> = BTreeMap::new();
        let mut node_left_states: BTreeMap<i64, Vec<u32>> = BTreeMap::new();
        let ends = |l: &GraphLanelet<'_>, reversed: bool| {
            let (r, lft) = (l.right_nodes, l.left_nodes);
            if reversed {
                ((lft[lft.len() - 1], r[r.len() - 1]), (lft[0], r[0]))
            } else {
                ((r[0], lft[0]), (r[r.len() - 1], lft[lft.len() - 1]))
            }
        };
        for (i, l) in lanelets.iter().enumerate() {
            if !l.routable {
                continue;
            }
            for reversed in [false, true] {
                if reversed && !l.bidirectional {
                    continue;
                }
                let state = (2 * i + reversed as usize) as u32;
                valid[state as usize] = true;
                by_start.entry(ends(l, reversed).0).or_default().push(state);
                let (right, left) =
                    if reversed { (l.left_nodes, l.right_nodes) } else { (l.right_nodes, l.left_nodes) };
                for (nodes, index) in [(right, &mut node_states), (left, &mut node_left_states)] {
                    for node in nodes {
                        let v = index.entry(*node).or_default();
                        if v.last() != Some(&state) {
                            v.push(state);
                        }
                    }
                }
            }
        }
        let lengths: Vec<f64> = (0..2 * n).map(|state| lanelets[state / 2].length).collect();
        let state_ends: Vec<DVec2> = (0..2 * n)
            .map(|state| {
                let (first, last) = lanelets[state / 2].centre_ends;
                if state % 2 == 1 { first } else { last }
            })
            .collect();
        let mut successors = vec![Vec::new(); 2 * n];
        if let Some(explicit) = explicit {
            for (i, next) in explicit.iter().enumerate() {
                if valid[2 * i] {
                    successors[2 * i] = next.iter().filter(|&&j| valid[2 * j]).map(|&j| (2 * j) as u32).collect();
                }
            }
            return RoutingGraph { successors, node_states, node_left_states, lengths, ends: state_ends };
        }
        for (state, ok) in valid.iter().enumerate() {
            if *ok {
                let l = &lanelets[state / 2];
                if let Some(next) = by_start.get(&ends(l, state % 2 == 1).1) {
                    successors[state] = next.iter().copied().filter(|&s| s as usize != state).collect();
                }
            }
        }
        RoutingGraph { successors, node_states, node_left_states, lengths, ends: state_ends }
    }
}
