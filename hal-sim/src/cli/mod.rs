//! Parts only the command line needs: progress bars, wrapped help, the live demo and the
//! field map.

pub mod demo;
pub mod field_map;
pub mod help;
pub mod progress;
