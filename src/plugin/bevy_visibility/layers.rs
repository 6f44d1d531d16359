//! Bevy's render-layer test between a view and an entity.

use bevy_camera::visibility::RenderLayers;
use bevy_ecs::entity::Entity;

/// Whether the view of entity `view` (a camera, or a light's shadow
/// views), on layers `view_mask`, renders `entity` on layers `entity_mask`,
/// as Bevy decides it.
///
/// Bevy's `RenderLayers::intersects` answers yes before it compares any
/// layer when both sides are the same memory, and Bevy's systems hand it
/// the components themselves (or the one static default where an entity
/// has none). So the view's own entity always passes, even with
/// `RenderLayers::none()`: a camera, which Bevy's culling tests as any
/// entity with `Visibility`, or a light that also casts shadows.
#[inline]
fn renders(
    view: Entity,
    view_mask: &RenderLayers,
    entity: Entity,
    entity_mask: Option<&RenderLayers>,
) -> bool {
    entity == view || view_mask.intersects(entity_mask.unwrap_or_default())
}

/// A view's layers as its layer test reads them: the view's entity, its
/// layers (the default where it has none), and whether it renders the
/// entities without layers, which is one answer for all of them: most
/// renderables have no layers, and Bevy's compare of the view's layers
/// with the default, one out-of-line call per entity and view, is made once
/// per view instead.
pub(super) struct ViewLayers {
    view: Entity,
    mask: RenderLayers,
    renders_unlayered: bool,
}

impl ViewLayers {
    /// The layers of the view of entity `view`, `mask` its `RenderLayers`
    /// if it has them.
    pub(super) fn new(view: Entity, mask: Option<&RenderLayers>) -> Self {
        let mask = mask.cloned().unwrap_or_default();
        ViewLayers {
            view,
            renders_unlayered: mask.intersects(Default::default()),
            mask,
        }
    }

    /// The view's entity.
    pub(super) fn view(&self) -> Entity {
        self.view
    }

    /// [`renders`] for this view.
    #[inline]
    pub(super) fn renders(&self, entity: Entity, entity_mask: Option<&RenderLayers>) -> bool {
        match entity_mask {
            Some(mask) => renders(self.view, &self.mask, entity, Some(mask)),
            None => self.renders_unlayered || entity == self.view,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bevy's own `intersects` is the oracle: on the same component (the
    /// view's own entity), on the same static default (an entity without
    /// layers under a view without), and on two components of equal value
    /// (two entities).
    #[test]
    fn answers_as_bevy_on_the_same_and_on_other_memory() {
        let view = Entity::from_raw_u32(1).unwrap();
        let other = Entity::from_raw_u32(2).unwrap();
        let masks = [
            RenderLayers::none(),
            RenderLayers::layer(0),
            RenderLayers::layer(1),
            RenderLayers::from_layers(&[0, 70]),
            RenderLayers::from_layers(&[70]),
        ];
        for mask in &masks {
            assert_eq!(
                renders(view, mask, view, Some(mask)),
                mask.intersects(mask),
                "{mask:?} on its own entity"
            );
            assert!(renders(view, mask, view, Some(mask)));
            for entity_mask in &masks {
                let copy = entity_mask.clone();
                assert_eq!(
                    renders(view, mask, other, Some(&copy)),
                    mask.intersects(&copy),
                    "{mask:?} against {entity_mask:?}"
                );
            }
        }
        let none = RenderLayers::none();
        assert!(!renders(view, &none, other, Some(&RenderLayers::none())));
        let default: &RenderLayers = Default::default();
        assert_eq!(
            renders(view, default, other, None),
            default.intersects(Default::default())
        );
        assert_eq!(
            renders(view, default, view, None),
            default.intersects(Default::default())
        );
    }

    /// A view's layers answer as [`renders`] does for every pair of masks,
    /// with and without layers on either side, for the view's own entity
    /// and another. Fails if the answer for entities without layers is not
    /// the view's own.
    #[test]
    fn a_view_s_layers_answer_as_the_test_per_entity() {
        let view = Entity::from_raw_u32(1).unwrap();
        let other = Entity::from_raw_u32(2).unwrap();
        let masks = [
            None,
            Some(RenderLayers::none()),
            Some(RenderLayers::layer(0)),
            Some(RenderLayers::layer(1)),
            Some(RenderLayers::from_layers(&[0, 70])),
            Some(RenderLayers::from_layers(&[70])),
        ];
        for view_mask in &masks {
            let layers = ViewLayers::new(view, view_mask.as_ref());
            let view_mask = view_mask.as_ref().unwrap_or_default();
            for entity_mask in &masks {
                // Another entity's own component (the view's is never the
                // same memory as an entity's but its own).
                let entity_mask = entity_mask.clone();
                for entity in [view, other] {
                    assert_eq!(
                        layers.renders(entity, entity_mask.as_ref()),
                        renders(view, view_mask, entity, entity_mask.as_ref()),
                        "{view_mask:?} against {entity_mask:?}"
                    );
                }
            }
        }
    }
}
