//! The task pool's size a run asks for: `BEVY_RTREE_THREADS` threads if
//! set, so that a run means the same on any machine (`scripts/scaling.sh`
//! sets it for each column of its table).

/// The threads `BEVY_RTREE_THREADS` asks for, if it is set to a number.
pub fn threads_wanted() -> Option<usize> {
    std::env::var("BEVY_RTREE_THREADS")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
}
