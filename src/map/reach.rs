//! Which routing states a route can join: the graph's strongly connected components (Tarjan's
//! algorithm, without recursion) and, for each component a search starts from, the set of
//! components it reaches (a bit set, filled the first time that component is asked about).
//!
//! A route search between two states no path joins searches everything the start reaches before
//! it gives up. On a grid of two lanes each way, where a route keeps its lane (left lanes turn left,
//! right lanes turn right), that is half of all random lanelet pairs: random trips spent most of
//! a town's set-up on searches that found nothing. [`Reach::may_reach`] answers in O(1) once a
//! component's set is filled (O(components + edges), once); it never says "no" where a route
//! exists, so a search it lets through finds the same route as before.

use std::sync::OnceLock;

/// Reachability between the states of a routing graph, computed on first use.
#[derive(Clone, Default)]
pub(crate) struct Reach {
    components: OnceLock<Components>,
}

impl std::fmt::Debug for Reach {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let count = self.components.get().map(|c| c.next.len());
        f.debug_struct("Reach").field("components", &count).finish()
    }
}

#[derive(Clone)]
struct Components {
    /// State -> its component.
    of: Vec<u32>,
    /// Component -> the other components one of its states leads to (each once).
    next: Vec<Vec<u32>>,
    /// Component -> the components it reaches (itself included), one bit each; filled on the
    /// first query from that component.
    reached: Vec<OnceLock<Box<[u64]>>>,
}

impl Reach {
    /// Whether a route may lead from state `from` to state `to` over `successors` (the graph this
    /// `Reach` belongs to: the same on every call). `false` only where no sequence of successors
    /// joins them; `true` for a state and itself (whether a loop returns to it is not asked).
    pub(crate) fn may_reach(&self, successors: &[Vec<u32>], from: u32, to: u32) -> bool {
        let c = self.components.get_or_init(|| Components::new(successors));
        let (Some(&a), Some(&b)) = (c.of.get(from as usize), c.of.get(to as usize)) else {
            return true;
        };
        if a == b {
            return true;
        }
        let bits = c.reached[a as usize].get_or_init(|| c.closure(a));
        bits[b as usize / 64] >> (b % 64) & 1 == 1
    }
}

impl Components {
    fn new(successors: &[Vec<u32>]) -> Components {
        let (of, count) = strongly_connected(successors);
        let mut next = vec![Vec::new(); count];
        for (v, list) in successors.iter().enumerate() {
            let a = of[v];
            for &w in list {
                let b = of[w as usize];
                if b != a {
                    next[a as usize].push(b);
                }
            }
        }
        for list in &mut next {
            list.sort_unstable();
            list.dedup();
        }
        Components { of, next, reached: (0..count).map(|_| OnceLock::new()).collect() }
    }

    /// The components `from` reaches, itself included, as bits (a depth-first walk over the
    /// components).
    fn closure(&self, from: u32) -> Box<[u64]> {
        let mut bits = vec![0u64; self.next.len().div_ceil(64)].into_boxed_slice();
        let mut todo = vec![from];
        bits[from as usize / 64] |= 1 << (from % 64);
        while let Some(a) = todo.pop() {
            for &b in &self.next[a as usize] {
                let (word, bit) = (b as usize / 64, 1u64 << (b % 64));
                if bits[word] & bit == 0 {
                    bits[word] |= bit;
                    todo.push(b);
                }
            }
        }
        bits
    }
}

/// Tarjan's strongly connected components of the graph `successors` (state -> next states), with
/// an explicit stack instead of recursion (a long chain of lanelets would overflow the thread's
/// stack): (component of every state, number of components).
fn strongly_connected(successors: &[Vec<u32>]) -> (Vec<u32>, usize) {
    let n = successors.len();
    let mut t = Tarjan {
        index: vec![UNSEEN; n],
        low: vec![0; n],
        on_stack: vec![false; n],
        stack: Vec::new(),
        calls: Vec::new(),
        next_index: 0,
    };
    let mut of = vec![UNSEEN; n];
    let mut count = 0u32;
    for root in 0..n {
        if t.index[root] != UNSEEN {
            continue;
        }
        t.enter(root);
        while let Some(&(v, k)) = t.calls.last() {
            let v = v as usize;
            if let Some(&w) = successors[v].get(k) {
                if let Some(top) = t.calls.last_mut() {
                    top.1 += 1;
                }
                let w = w as usize;
                if w >= n {
                    continue;
                }
                if t.index[w] == UNSEEN {
                    t.enter(w);
                } else if t.on_stack[w] {
                    t.low[v] = t.low[v].min(t.index[w]);
                }
                continue;
            }
            t.calls.pop();
            if let Some(&(u, _)) = t.calls.last() {
                t.low[u as usize] = t.low[u as usize].min(t.low[v]);
            }
            if t.low[v] == t.index[v] {
                while let Some(w) = t.stack.pop() {
                    t.on_stack[w as usize] = false;
                    of[w as usize] = count;
                    if w as usize == v {
                        break;
                    }
                }
                count += 1;
            }
        }
    }
    (of, count as usize)
}

/// A state not reached yet (in [`Tarjan::index`]) or in no component yet.
const UNSEEN: u32 = u32::MAX;

/// The walk of [`strongly_connected`].
struct Tarjan {
    /// Order in which each state was entered ([`UNSEEN`]: not yet).
    index: Vec<u32>,
    /// Lowest `index` reachable from each state through the walk and one edge back.
    low: Vec<u32>,
    /// Whether each state is on `stack`.
    on_stack: Vec<bool>,
    /// States entered whose component is not known yet.
    stack: Vec<u32>,
    /// The walk's path: (state, how many of its successors were looked at).
    calls: Vec<(u32, usize)>,
    next_index: u32,
}

impl Tarjan {
    fn enter(&mut self, v: usize) {
        self.index[v] = self.next_index;
        self.low[v] = self.next_index;
        self.next_index += 1;
        self.stack.push(v as u32);
        self.on_stack[v] = true;
        self.calls.push((v as u32, 0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether `to` can be reached from `from` by one or more steps, or is `from` (a plain
    /// breadth-first search: what `may_reach` must agree with).
    fn reaches(successors: &[Vec<u32>], from: u32, to: u32) -> bool {
        let mut seen = vec![false; successors.len()];
        let mut todo = vec![from];
        seen[from as usize] = true;
        while let Some(v) = todo.pop() {
            if v == to {
                return true;
            }
            for &w in &successors[v as usize] {
                if !seen[w as usize] {
                    seen[w as usize] = true;
                    todo.push(w);
                }
            }
        }
        false
    }

    #[test]
    fn reachability_agrees_with_a_search_on_every_pair() {
        // Two rings (0-1-2 and 5-6), a chain from the first to the second through 3 and 4, a
        // state only reached (7), one leading only away (8 -> 0), one alone (9), a loop on 10.
        let successors: Vec<Vec<u32>> = vec![
            vec![1],
            vec![2],
            vec![0, 3],
            vec![4],
            vec![5],
            vec![6],
            vec![5, 7],
            vec![],
            vec![0],
            vec![],
            vec![10],
        ];
        let reach = Reach::default();
        let mut unreachable = 0;
        for a in 0..successors.len() as u32 {
            for b in 0..successors.len() as u32 {
                let expected = reaches(&successors, a, b);
                assert_eq!(reach.may_reach(&successors, a, b), expected, "{a} -> {b}");
                unreachable += usize::from(!expected);
            }
        }
        // The check must have had pairs to refuse, or agreeing would prove nothing.
        assert!(unreachable > 40, "{unreachable}");
    }

    #[test]
    fn a_long_chain_does_not_overflow_the_stack() {
        let n = 200_000u32;
        let successors: Vec<Vec<u32>> = (0..n).map(|i| if i + 1 < n { vec![i + 1] } else { vec![] }).collect();
        let reach = Reach::default();
        assert!(reach.may_reach(&successors, 0, n - 1));
        assert!(!reach.may_reach(&successors, n - 1, 0));
    }
}
