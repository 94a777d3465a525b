//! The routing graph: directed lanelets and which follows which (by shared bound end nodes),
//! built from plain lanelet data so the lanelet layer needs nothing of routing.

use glam::DVec2;

use super::reach::Reach;

/// Directed lanelets as a graph: state `2 * index + reversed`; reversed states exist only for
/// `one_way=no` lanelets, and no state exists for lanelets a vehicle may not drive.
#[derive(Debug, Clone, Default)]
pub(crate) struct RoutingGraph {
    pub(crate) successors: Vec<Vec<u32>>,
    /// Node id -> states whose right bound (in their driving direction) contains the node: the
    /// 2015 rule (seed §3.3.2) for which lanelets a start or end node selects.
    pub(crate) node_states: NodeStates,
    /// Node id -> states whose left bound (in their driving direction) contains the node: the
    /// fallback for nodes on no right bound (Lanelet2 maps tag the left marking too).
    pub(crate) node_left_states: NodeStates,
    /// Centre-line length of every state [m] (indexed like `successors`): the searches read
    /// these compact arrays, not the lanelets (a cache miss each on a big map).
    pub(crate) lengths: Vec<f64>,
    /// Where every state's centre line ends in its driving direction (A*'s heuristic).
    pub(crate) ends: Vec<DVec2>,
    /// Which states a route can join ([`Reach::may_reach`]): searches between states no path
    /// joins are refused without searching.
    pub(crate) reach: Reach,
}

/// Node id -> states (rising), as rising node ids and one flat list of states: a list per node in
/// a tree cost an allocation and a tree insert for each of a big map's hundreds of thousands of
/// bound nodes.
#[derive(Debug, Clone, Default)]
pub(crate) struct NodeStates {
    /// Node ids, rising.
    nodes: Vec<i64>,
    /// The states of `nodes[k]` are `states[starts[k]..starts[k + 1]]` (one more entry than `nodes`).
    starts: Vec<u32>,
    states: Vec<u32>,
}

impl NodeStates {
    /// From (node, state) pairs in any order, repeats allowed.
    fn from_pairs(mut pairs: Vec<(i64, u32)>) -> NodeStates {
        pairs.sort_unstable();
        pairs.dedup();
        let mut out = NodeStates { nodes: Vec::new(), starts: Vec::new(), states: Vec::with_capacity(pairs.len()) };
        for (node, state) in pairs {
            if out.nodes.last() != Some(&node) {
                out.nodes.push(node);
                out.starts.push(out.states.len() as u32);
            }
            out.states.push(state);
        }
        out.starts.push(out.states.len() as u32);
        out
    }

    /// The states of `node`, rising (empty when it is on no bound of that side).
    pub(crate) fn get(&self, node: i64) -> &[u32] {
        match self.nodes.binary_search(&node) {
            Ok(k) => &self.states[self.starts[k] as usize..self.starts[k + 1] as usize],
            Err(_) => &[],
        }
    }

    /// The node ids, rising.
    pub(crate) fn nodes(&self) -> &[i64] {
        &self.nodes
    }
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
    /// Whether a route may lead from state `from` to state `to` ([`Reach::may_reach`]: `false`
    /// only where none does).
    pub(crate) fn may_reach(&self, from: u32, to: u32) -> bool {
        self.reach.may_reach(&self.successors, from, to)
    }

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
        // (start, state) and (node, state) pairs, sorted below: states rise in push order, so
        // each start's or node's states come out rising as the lists of a map would hold them.
        let mut by_start: Vec<((i64, i64), u32)> = Vec::with_capacity(n);
        let bound_nodes: usize = lanelets.iter().map(|l| l.right_nodes.len().max(l.left_nodes.len())).sum();
        let mut right_pairs: Vec<(i64, u32)> = Vec::with_capacity(bound_nodes);
        let mut left_pairs: Vec<(i64, u32)> = Vec::with_capacity(bound_nodes);
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
                by_start.push((ends(l, reversed).0, state));
                let (right, left) =
                    if reversed { (l.left_nodes, l.right_nodes) } else { (l.right_nodes, l.left_nodes) };
                right_pairs.extend(right.iter().map(|&node| (node, state)));
                left_pairs.extend(left.iter().map(|&node| (node, state)));
            }
        }
        let node_states = NodeStates::from_pairs(right_pairs);
        let node_left_states = NodeStates::from_pairs(left_pairs);
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
            return RoutingGraph {
                successors,
                node_states,
                node_left_states,
                lengths,
                ends: state_ends,
                reach: Reach::default(),
            };
        }
        by_start.sort_unstable();
        for (state, ok) in valid.iter().enumerate() {
            if *ok {
                let end = ends(&lanelets[state / 2], state % 2 == 1).1;
                let from = by_start.partition_point(|(start, _)| *start < end);
                let next = by_start[from..].iter().take_while(|(start, _)| *start == end);
                successors[state] = next.map(|&(_, s)| s).collect();
            }
        }
        RoutingGraph { successors, node_states, node_left_states, lengths, ends: state_ends, reach: Reach::default() }
    }
}
