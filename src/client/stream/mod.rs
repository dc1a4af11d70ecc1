//! Streaming: [`fetch`] (the request scheduler and its decoded-tile cache, behind
//! [`fetch::Transport`]), [`http`] (a minimal blocking HTTP/1.1 GET), [`flight`] (camera
//! flights) and [`session`] (a streaming session against `terrastream serve`, flight replay
//! and its statistics), with the `gpu` feature [`view`] (what a session draws, rendered).

pub mod fetch;
pub mod flight;
pub mod http;
pub mod session;
#[cfg(feature = "gpu")]
pub mod view;
