//! Why the receiver refused an input.

use crate::estimate::EstimateError;
use crate::frontend::FrontendError;
use crate::guidance::classic::ClassicError;
use crate::motion::MotionError;

/// Why an input was refused (the receiver's state is then unchanged).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AppError {
    /// The IMU sample was refused by the motion pipeline.
    #[error("IMU sample refused: {0}")]
    Motion(MotionError),
    /// The pulse was refused by the estimator.
    #[error("pulse refused by the estimator: {0}")]
    Estimate(EstimateError),
    /// The ADC sample was refused by the front end.
    #[error("ADC sample refused: {0}")]
    Frontend(FrontendError),
    /// A time or vector was NaN or infinite.
    #[error("time or vector NaN or infinite")]
    NonFinite,
    /// Mark pressed with no victim being guided to.
    #[error("mark pressed with no victim guided to")]
    NoTarget,
    /// The pulse or configuration was refused by the classic mode.
    #[error("refused by the classic mode: {0}")]
    Classic(ClassicError),
}

impl From<ClassicError> for AppError {
    fn from(e: ClassicError) -> Self {
        AppError::Classic(e)
    }
}

impl From<MotionError> for AppError {
    fn from(e: MotionError) -> Self {
        AppError::Motion(e)
    }
}

impl From<EstimateError> for AppError {
    fn from(e: EstimateError) -> Self {
        AppError::Estimate(e)
    }
}

impl From<FrontendError> for AppError {
    fn from(e: FrontendError) -> Self {
        AppError::Frontend(e)
    }
}
