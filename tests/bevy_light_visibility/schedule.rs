//! The app's systems ordered against Bevy's light systems keep their
//! order against the systems that replace them.

use super::*;

/// Systems an app orders after or before Bevy's visibility systems stay
/// ordered so against the systems that replace them: a probe that reads
/// the lists `.after(check_point_light_mesh_visibility)`,
/// `.after(check_dir_light_mesh_visibility)` or
/// `.after(check_visibility_cpu_culling)` never reads last frame's lists,
/// and one that writes what a light system reads
/// `.before(check_point_light_mesh_visibility)` or
/// `.before(check_dir_light_mesh_visibility)` is seen in the same frame.
/// Checked on the built schedule: no system that accesses what a probe
/// writes or reads runs unordered with it, in either App.
#[test]
fn systems_ordered_against_bevy_s_are_ordered_against_the_index_s() {
    use bevy_camera::visibility::{VisibleEntities, check_visibility_cpu_culling};
    use bevy_ecs::schedule::{IntoSystemSet, Schedules, SystemSet};
    use bevy_light::{check_dir_light_mesh_visibility, check_point_light_mesh_visibility};

    fn light_probe(lists: Query<&CubemapVisibleEntities>) {
        let _ = lists.iter().count();
    }
    fn cascade_probe(lists: Query<&CascadesVisibleEntities>) {
        let _ = lists.iter().count();
    }
    fn camera_probe(lists: Query<&VisibleEntities>) {
        let _ = lists.iter().count();
    }
    fn visibility_probe(marks: Query<&ViewVisibility>) {
        let _ = marks.iter().filter(|v| v.get()).count();
    }
    fn point_writer(mut lists: Query<&mut CubemapVisibleEntities>) {
        lists.iter_mut().for_each(|mut l| l.set_changed());
    }
    fn cascade_writer(mut lists: Query<&mut CascadesVisibleEntities>) {
        lists.iter_mut().for_each(|mut l| l.set_changed());
    }
    let probes = [
        light_probe.into_system_set().intern(),
        cascade_probe.into_system_set().intern(),
        camera_probe.into_system_set().intern(),
        visibility_probe.into_system_set().intern(),
        point_writer.into_system_set().intern(),
        cascade_writer.into_system_set().intern(),
    ];
    // The readers after and the writers before in Apps of their own: a
    // reader after a system and a writer before it are ordered through
    // the set the system leaves behind, which would hide a writer the
    // replacement does not follow.
    for (writers, ours) in [(false, false), (false, true), (true, false), (true, true)] {
        let mut app = app(ours);
        if writers {
            app.add_systems(
                PostUpdate,
                (
                    point_writer.before(check_point_light_mesh_visibility),
                    cascade_writer.before(check_dir_light_mesh_visibility),
                ),
            );
        } else {
            app.add_systems(
                PostUpdate,
                (
                    light_probe.after(check_point_light_mesh_visibility),
                    cascade_probe.after(check_dir_light_mesh_visibility),
                    camera_probe.after(check_visibility_cpu_culling),
                    // Bevy's directional light marks its casters by
                    // command, reading no caster's `ViewVisibility`: a
                    // reader after the point lights needs no other order.
                    visibility_probe
                        .after(check_point_light_mesh_visibility)
                        .before(VisibilitySystems::MarkNewlyHiddenEntitiesInvisible),
                ),
            );
        }
        app.update();
        let schedule = app.world().resource::<Schedules>().get(PostUpdate).unwrap();
        // Between runs the systems are held by the schedule's executable;
        // each is known by its function's set.
        let is_probe: HashMap<_, bool> = schedule
            .systems()
            .unwrap()
            .map(|(key, system)| {
                let sets = system.default_system_sets();
                (key, probes.iter().any(|probe| sets.contains(probe)))
            })
            .collect();
        let unordered: Vec<_> = schedule
            .graph()
            .conflicting_systems()
            .0
            .iter()
            .filter(|(a, b, _)| is_probe[a] != is_probe[b])
            .collect();
        assert!(
            unordered.is_empty(),
            "writers {writers}, ours {ours}: {unordered:?}"
        );
    }
}

/// bevy_light's two systems are not ordered against each other: an app's
/// systems between them (`a` after one, `b` before the other, `a` before
/// `b`) must not close a cycle around their replacements, and the app runs
/// as with Bevy's systems.
#[test]
fn systems_between_bevy_s_two_light_systems_make_no_cycle() {
    use bevy_light::{check_dir_light_mesh_visibility, check_point_light_mesh_visibility};

    fn a() {}
    fn b() {}
    for ours in [false, true] {
        let mut app = app(ours);
        app.add_systems(
            PostUpdate,
            (
                a.after(check_dir_light_mesh_visibility),
                b.before(check_point_light_mesh_visibility),
            )
                .chain(),
        );
        app.update();
        app.update();
    }
}
