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
pub(super) fn renders(
    view: Entity,
    view_mask: &RenderLayers,
    entity: Entity,
    entity_mask: Option<&RenderLayers>,
) -> bool {
    entity == view || view_mask.intersects(entity_mask.unwrap_or_default())
}

/// [`renders`] for every entity without layers other than the view's own:
/// the same answer for all of them, so a view finds it once.
pub(super) fn renders_unlayered(view_mask: &RenderLayers) -> bool {
    view_mask.intersects(Default::default())
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
            assert_eq!(
                renders_unlayered(mask),
                renders(view, mask, other, None),
                "{mask:?} against an entity without layers"
            );
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
}
