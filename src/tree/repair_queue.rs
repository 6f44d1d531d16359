//! The queue of level-1 nodes waiting for [`RTree::optimize`](super::RTree::optimize).

use super::node::NIL;

/// Level-1 nodes whose churn crossed the repack threshold, each at most
/// once, and only while it is live.
///
/// A node freed while queued (condensed away, or the old root) leaves the
/// queue at once: otherwise the pool would recycle it, churn would queue it
/// again, and the queue would grow past the number of nodes it can name.
/// Membership is kept per node (its place in the queue), so that entering,
/// leaving and testing cost O(1).
#[derive(Clone, Debug, Default)]
pub(super) struct RepairQueue {
    /// The queued nodes, in no particular order.
    queued: Vec<u32>,
    /// Per node of the pool: its index in `queued`, or `NIL`.
    place: Vec<u32>,
}

impl RepairQueue {
    /// Number of queued nodes.
    pub fn len(&self) -> usize {
        self.queued.len()
    }

    /// The bytes it holds.
    pub fn memory(&self) -> usize {
        (self.queued.capacity() + self.place.capacity()) * std::mem::size_of::<u32>()
    }

    /// Forgets every node.
    pub fn clear(&mut self) {
        self.queued.clear();
        self.place.clear();
    }

    /// Queues `node` unless it is queued already.
    pub fn push(&mut self, node: u32) {
        if self.place.len() <= node as usize {
            self.place.resize(node as usize + 1, NIL);
        }
        let place = &mut self.place[node as usize];
        if *place == NIL {
            *place = self.queued.len() as u32;
            self.queued.push(node);
        }
    }

    /// Takes `node` out of the queue if it is there.
    pub fn remove(&mut self, node: u32) {
        let Some(slot) = self.place.get_mut(node as usize) else {
            return;
        };
        let place = std::mem::replace(slot, NIL);
        if place == NIL {
            return;
        }
        self.queued.swap_remove(place as usize);
        if let Some(&moved) = self.queued.get(place as usize) {
            self.place[moved as usize] = place;
        }
    }

    /// Takes one queued node out.
    pub fn pop(&mut self) -> Option<u32> {
        let node = self.queued.pop()?;
        self.place[node as usize] = NIL;
        Some(node)
    }

    /// The queued nodes, for validation.
    pub fn nodes(&self) -> &[u32] {
        &self.queued
    }

    /// Whether the per-node places agree with the queue.
    pub fn is_consistent(&self) -> bool {
        let listed = self
            .queued
            .iter()
            .enumerate()
            .all(|(i, &node)| self.place.get(node as usize) == Some(&(i as u32)));
        let placed = self.place.iter().filter(|&&p| p != NIL).count();
        listed && placed == self.queued.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_node_is_queued_once_and_leaves_when_removed() {
        let mut queue = RepairQueue::default();
        queue.push(3);
        queue.push(5);
        queue.push(3);
        assert_eq!(queue.len(), 2);
        queue.remove(3);
        queue.remove(3);
        assert_eq!(queue.nodes(), [5]);
        assert!(queue.is_consistent());
        queue.push(7);
        queue.remove(5);
        assert_eq!(queue.pop(), Some(7));
        assert_eq!(queue.pop(), None);
        assert!(queue.is_consistent());
    }
}
