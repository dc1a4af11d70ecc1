//! Streaming: [`fetch`] (the request scheduler and its decoded-tile cache, behind
//! [`fetch::Transport`]), [`http`] (a minimal blocking HTTP/1.1 GET), [`flight_path`] (camera
//! flights: keyed poses and their interpolation), [`session`] (a streaming session against
//! `terrastream serve`), [`replay`] (flying a session along a flight path, its frames and
//! statistics) and, with the `gpu` feature, [`view`] (what a session draws, rendered).
//!
//! Imports run one way: `replay` uses `session` and `view`; `view` uses `session`.

pub mod fetch;
pub mod flight_path;
pub mod http;
pub mod replay;
pub mod session;
#[cfg(feature = "gpu")]
pub mod view;
