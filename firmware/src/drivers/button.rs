//! The mark button, debounced (generic over `embedded_hal::digital::InputPin`: a GPIO
//! on the board, a mock in the tests).

/// The mark button: an active-low push button (pull-up, closes to ground) read through
/// `embedded_hal::digital::InputPin` and debounced by polling.
#[derive(Debug)]
pub struct MarkButton<P> {
    pin: P,
    /// Consecutive polls that read "pressed".
    low: u8,
    /// The current press was already reported.
    reported: bool,
}

impl<P: embedded_hal::digital::InputPin> MarkButton<P> {
    /// Polls "pressed" in a row that make a press (30 ms at the 100 Hz IMU tick: longer
    /// than a switch's bounce, far shorter than a deliberate press).
    pub const DEBOUNCE_POLLS: u8 = 3;

    /// A button on `pin`.
    pub fn new(pin: P) -> Self {
        Self {
            pin,
            low: 0,
            reported: false,
        }
    }

    /// Reads the pin once; `true` exactly once per press. A read error counts as released.
    pub fn poll(&mut self) -> bool {
        if self.pin.is_low().unwrap_or(false) {
            self.low = self.low.saturating_add(1);
            if self.low >= Self::DEBOUNCE_POLLS && !self.reported {
                self.reported = true;
                return true;
            }
        } else {
            self.low = 0;
            self.reported = false;
        }
        false
    }

    /// Gives the pin back.
    pub fn release(self) -> P {
        self.pin
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mark_button_debounces_and_reports_once_per_press() {
        use embedded_hal_mock::eh1::digital::{Mock, State, Transaction};
        let reads = [
            State::Low,  // bounce
            State::High, //
            State::Low,
            State::Low,
            State::Low, // pressed: reported here
            State::Low,
            State::Low, // held: not again
            State::High,
            State::Low,
            State::Low,
            State::Low, // second press
        ];
        let tx: Vec<Transaction> = reads.iter().map(|s| Transaction::get(*s)).collect();
        let mut b = MarkButton::new(Mock::new(&tx));
        let got: Vec<bool> = reads.iter().map(|_| b.poll()).collect();
        let presses: Vec<usize> = got
            .iter()
            .enumerate()
            .filter(|(_, p)| **p)
            .map(|(i, _)| i)
            .collect();
        assert_eq!(presses, vec![4, 10]);
        b.release().done();
    }
}
