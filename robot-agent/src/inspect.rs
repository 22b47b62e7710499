//! `robot-agent inspect` (filled in below).
