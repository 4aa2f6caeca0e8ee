//! Parts only the command line needs: progress bars, the live demo and the field map.

pub mod demo;
pub mod field_map;
pub mod progress;
