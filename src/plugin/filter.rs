//! Which entities a query may report: [`SpatialQueryFilter`].

use std::sync::Arc;

use bevy_ecs::prelude::*;

/// Which entities a query may report: every entity but the excluded ones,
/// and of those only the ones a predicate (if any) accepts. The default
/// filter lets every entity through.
///
/// Filtered queries answer exactly as if the filtered-out entities were not
/// in the index: the first hit of a ray is the first *allowed* hit, the
/// `k` nearest are the `k` nearest allowed entities. Every query of
/// [`SpatialQuery`](super::SpatialQuery) takes one, and every
/// [`RayCaster`](super::RayCaster) has one (and ignores its own entity
/// unless told otherwise).
///
/// ```
/// use bevy_ecs::entity::Entity;
/// use bevy_rtree::plugin::SpatialQueryFilter;
///
/// let (me, ally, enemy) = (Entity::from_bits(1), Entity::from_bits(2), Entity::from_bits(3));
/// let filter = SpatialQueryFilter::excluding([me]).with_predicate(move |e| e != ally);
/// assert!(!filter.allows(me) && !filter.allows(ally) && filter.allows(enemy));
/// assert!(SpatialQueryFilter::default().allows(me));
/// ```
#[derive(Clone, Default)]
pub struct SpatialQueryFilter {
    excluded: Vec<Entity>,
    predicate: Option<Arc<dyn Fn(Entity) -> bool + Send + Sync>>,
}

impl SpatialQueryFilter {
    /// A filter that lets every entity through but `entities`.
    pub fn excluding(entities: impl IntoIterator<Item = Entity>) -> Self {
        SpatialQueryFilter {
            excluded: entities.into_iter().collect(),
            predicate: None,
        }
    }

    /// The same filter, also excluding `entity`.
    pub fn with_excluded(mut self, entity: Entity) -> Self {
        self.excluded.push(entity);
        self
    }

    /// The same filter, letting through only entities `predicate` accepts
    /// (replacing any predicate it had).
    pub fn with_predicate(
        mut self,
        predicate: impl Fn(Entity) -> bool + Send + Sync + 'static,
    ) -> Self {
        self.predicate = Some(Arc::new(predicate));
        self
    }

    /// The excluded entities.
    pub fn excluded(&self) -> &[Entity] {
        &self.excluded
    }

    /// Whether the filter lets every entity through.
    pub fn allows_all(&self) -> bool {
        self.excluded.is_empty() && self.predicate.is_none()
    }

    /// Whether `entity` may be reported.
    #[inline]
    pub fn allows(&self, entity: Entity) -> bool {
        !self.excluded.contains(&entity) && self.predicate.as_ref().is_none_or(|p| p(entity))
    }
}

impl std::fmt::Debug for SpatialQueryFilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SpatialQueryFilter")
            .field("excluded", &self.excluded)
            .field(
                "predicate",
                &self.predicate.as_ref().map(|_| "Fn(Entity) -> bool"),
            )
            .finish()
    }
}
