//! Session logs and receiver configurations in and out: the spec's reader and writer,
//! `receiver.json`, `inspect`, and `replay` through the firmware's pipeline.

pub mod inspect;
pub mod receiver_config;
pub mod replay;
pub mod session;
pub mod sog_replay;
