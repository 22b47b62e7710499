//! The tick's messages written in place: a note, a string or a header set to a new value
//! while keeping its buffers, so that a controller's commands and diagnostics allocate
//! nothing once the team's shape is set.

use protocol::Header;

/// `note = value`, keeping `note`'s buffer.
pub fn set_note(note: &mut Option<String>, value: Option<&str>) {
    match (value, note) {
        (None, n) => *n = None,
        (Some(v), Some(n)) => set_string(n, v),
        (Some(v), n) => *n = Some(v.to_string()),
    }
}

/// `s = value`, keeping `s`'s buffer.
pub fn set_string(s: &mut String, value: &str) {
    if s != value {
        s.clear();
        s.push_str(value);
    }
}

/// A header's fields set in place (no new strings when they are unchanged).
pub fn set_header(h: &mut Header, team: &str, robot: Option<&str>, tick: u64, stamp_ns: u64) {
    h.version = protocol::PROTOCOL_VERSION;
    set_string(&mut h.team, team);
    match (robot, &mut h.robot) {
        (Some(r), Some(old)) => set_string(old, r),
        (r, old) => *old = r.map(str::to_string),
    }
    h.tick = tick;
    h.stamp_ns = stamp_ns;
}
