//! The reference board's pin map, checked against the Adafruit Feather STM32F405 Express.
//!
//! Every MCU pin the receiver uses is either on the Feather's header (and wired to the
//! receiver's chips there) or wired on the Feather itself (the battery divider, the
//! microSD slot). Sources: the Feather's schematic (Adafruit's
//! `Adafruit-Feather-STM32F405-Express-PCB`, nets `V_DIV` and `SD_DETECT`) and the
//! MicroPython board definition `ADAFRUIT_F405_EXPRESS/pins.csv`. [`ASSIGNMENTS`] is the
//! table the board binary follows; [`check`] (run by the unit tests) proves that each pin
//! is where the table says and that no pin serves two functions.
//!
//! | function | Feather pin | MCU pin | peripheral |
//! |---|---|---|---|
//! | antenna ADC ADS131M04: SCK | SCK | PB13 | SPI2 (AF5) |
//! | antenna ADC: MISO (DOUT) | MISO | PB14 | SPI2 |
//! | antenna ADC: MOSI (DIN) | MOSI | PB15 | SPI2 |
//! | antenna ADC: chip select (active low) | D10 | PB9 | GPIO output |
//! | antenna ADC: DRDY (active low) | D5 | PC7 | EXTI7 (EXTI9_5 interrupt) |
//! | IMU (BMI160 + LSM303AGR) and SSD1306 display: SCL | SCL | PB6 | I2C1 (AF4), also STEMMA QT |
//! | IMU and display: SDA | SDA | PB7 | I2C1, also STEMMA QT |
//! | session-log stream, 921 600 Bd | TX | PB10 | USART3 TX |
//! | mark button (to ground, internal pull-up) | D6 | PC6 | GPIO input |
//! | fault LED: the Feather's red LED, lit while a sensor fault holds (seen even when the display is the fault) | D13 | PC1 | GPIO output |
//! | battery voltage, ½ of BAT through the Feather's 2 × 100 kΩ divider | — (on board) | PA3 | ADC1 IN3 |
//! | buzzer (passive piezo to ground), guidance tones | D9 | PB8 | TIM4 CH3 PWM (AF2) |
//! | sound button (to ground, internal pull-up): mutes and unmutes the tones | D12 | PC2 | GPIO input |
//! | IF range switch of the antenna's analog chain (high = low range, `frontend::ranging`) | D11 | PC3 | GPIO output |
//! | microSD (session log): data 0–3 | — (on board) | PC8–PC11 | SDIO D0–D3 (AF12) |
//! | microSD: clock | — (on board) | PC12 | SDIO CK |
//! | microSD: command | — (on board) | PD2 | SDIO CMD |
//! | microSD: card detect (switch to ground, internal pull-up, low = card in) | — (on board) | PB12 | GPIO input |
//!
//! Not used and kept free: D8/PC0 (NeoPixel), the 2 MB SPI flash (PB3/PB4/PB5, CS PA15).
//! The card detect is **PB12**, which is why the ADC's chip select is not there: PB12 is
//! not on the header.

/// An MCU pin: port letter and number, e.g. `P('B', 12)` for PB12.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct P(pub char, pub u8);

/// Where a pin reaches the receiver's hardware.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Site {
    /// On the Feather's header, under this silkscreen label.
    Header(&'static str),
    /// Wired on the Feather itself to this net (no header pin).
    OnBoard(&'static str),
}

/// One function of the receiver bound to one MCU pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Assignment {
    /// What the pin does.
    pub function: &'static str,
    /// The MCU pin.
    pub pin: P,
    /// Where it is on the board.
    pub site: Site,
}

/// The Feather STM32F405 Express header: silkscreen label → MCU pin (every signal pin;
/// power, reset and EN pins carry no MCU pin).
pub const FEATHER_HEADER: [(&str, P); 20] = [
    ("A0", P('A', 4)),
    ("A1", P('A', 5)),
    ("A2", P('A', 6)),
    ("A3", P('A', 7)),
    ("A4", P('C', 4)),
    ("A5", P('C', 5)),
    ("SCK", P('B', 13)),
    ("MISO", P('B', 14)),
    ("MOSI", P('B', 15)),
    ("RX", P('B', 11)),
    ("TX", P('B', 10)),
    ("D5", P('C', 7)),
    ("D6", P('C', 6)),
    ("D9", P('B', 8)),
    ("D10", P('B', 9)),
    ("D11", P('C', 3)),
    ("D12", P('C', 2)),
    ("D13", P('C', 1)),
    ("SCL", P('B', 6)),
    ("SDA", P('B', 7)),
];

/// MCU pins wired on the Feather itself: net → MCU pin.
pub const FEATHER_ON_BOARD: [(&str, P); 13] = [
    ("V_DIV", P('A', 3)),
    ("SD_DETECT", P('B', 12)),
    ("SDIO_D0", P('C', 8)),
    ("SDIO_D1", P('C', 9)),
    ("SDIO_D2", P('C', 10)),
    ("SDIO_D3", P('C', 11)),
    ("SDIO_CLK", P('C', 12)),
    ("SDIO_CMD", P('D', 2)),
    ("NEOPIXEL", P('C', 0)),
    ("FLASH_SCK", P('B', 3)),
    ("FLASH_MISO", P('B', 4)),
    ("FLASH_MOSI", P('B', 5)),
    ("FLASH_CS", P('A', 15)),
];

/// The receiver's pins (the module table; the board binary binds exactly these).
pub const ASSIGNMENTS: [Assignment; 21] = [
    a("antenna ADC SCK", P('B', 13), Site::Header("SCK")),
    a("antenna ADC MISO", P('B', 14), Site::Header("MISO")),
    a("antenna ADC MOSI", P('B', 15), Site::Header("MOSI")),
    a("antenna ADC CS", ADC_CS, Site::Header("D10")),
    a("antenna ADC DRDY", ADC_DRDY, Site::Header("D5")),
    a("I2C1 SCL", I2C_SCL, Site::Header("SCL")),
    a("I2C1 SDA", I2C_SDA, Site::Header("SDA")),
    a("session log TX", P('B', 10), Site::Header("TX")),
    a("mark button", P('C', 6), Site::Header("D6")),
    a("fault LED", FAULT_LED, Site::Header("D13")),
    a("battery divider", BATTERY, Site::OnBoard("V_DIV")),
    a("buzzer", P('B', 8), Site::Header("D9")),
    a("sound button", P('C', 2), Site::Header("D12")),
    a("microSD D0", P('C', 8), Site::OnBoard("SDIO_D0")),
    a("microSD D1", P('C', 9), Site::OnBoard("SDIO_D1")),
    a("microSD D2", P('C', 10), Site::OnBoard("SDIO_D2")),
    a("microSD D3", P('C', 11), Site::OnBoard("SDIO_D3")),
    a("microSD CLK", P('C', 12), Site::OnBoard("SDIO_CLK")),
    a("microSD CMD", P('D', 2), Site::OnBoard("SDIO_CMD")),
    a("microSD card detect", SD_DETECT, Site::OnBoard("SD_DETECT")),
    a("IF range switch", IF_RANGE, Site::Header("D11")),
];

/// The microSD slot's card-detect switch (low with a card in).
pub const SD_DETECT: P = P('B', 12);

/// The antenna ADC's chip select (D10).
pub const ADC_CS: P = P('B', 9);
/// The antenna ADC's data-ready line (D5, EXTI7).
pub const ADC_DRDY: P = P('C', 7);
/// The shared I2C bus's clock (SCL), needed by the bus recovery as a GPIO.
pub const I2C_SCL: P = P('B', 6);
/// The shared I2C bus's data (SDA).
pub const I2C_SDA: P = P('B', 7);
/// The fault LED (the Feather's red LED on D13).
pub const FAULT_LED: P = P('C', 1);
/// The IF range switch's control (D11; high selects the low range).
pub const IF_RANGE: P = P('C', 3);
/// The battery divider's tap (ADC1 channel 3).
pub const BATTERY: P = P('A', 3);
/// The battery divider's ratio: BAT = ratio × V(PA3) (two 100 kΩ resistors).
pub const BATTERY_DIVIDER: f32 = 2.0;

const fn a(function: &'static str, pin: P, site: Site) -> Assignment {
    Assignment {
        function,
        pin,
        site,
    }
}

/// What is wrong with a pin map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PinMapError {
    /// The site named does not exist on the Feather (the function concerned).
    #[error("{0}: no such pin on the Feather")]
    UnknownSite(&'static str),
    /// The site exists but carries another MCU pin (the function concerned).
    #[error("{0}: the Feather pin named carries another MCU pin")]
    WrongPin(&'static str),
    /// Two functions share one MCU pin (the second function).
    #[error("{0}: MCU pin already used by another function")]
    Shared(&'static str),
    /// Two functions use the same EXTI line (the second function; EXTI lines are per pin
    /// number, whatever the port).
    #[error("{0}: EXTI line already used by another interrupt pin")]
    SharedExti(&'static str),
}

/// The MCU pin behind a site of the Feather, if the site exists.
pub fn site_pin(site: Site) -> Option<P> {
    let (table, name): (&[(&str, P)], &str) = match site {
        Site::Header(l) => (&FEATHER_HEADER, l),
        Site::OnBoard(n) => (&FEATHER_ON_BOARD, n),
    };
    table.iter().find(|(l, _)| *l == name).map(|(_, p)| *p)
}

/// Checks a pin map: every pin is at its stated site of the Feather, no pin is used
/// twice, and the interrupt pins (`exti`) use distinct EXTI lines.
pub fn check(assignments: &[Assignment], exti: &[P]) -> Result<(), PinMapError> {
    for (i, x) in assignments.iter().enumerate() {
        match site_pin(x.site) {
            None => return Err(PinMapError::UnknownSite(x.function)),
            Some(p) if p != x.pin => return Err(PinMapError::WrongPin(x.function)),
            Some(_) => {}
        }
        if assignments.iter().take(i).any(|y| y.pin == x.pin) {
            return Err(PinMapError::Shared(x.function));
        }
        if exti.contains(&x.pin)
            && assignments
                .iter()
                .take(i)
                .any(|y| exti.contains(&y.pin) && y.pin.1 == x.pin.1)
        {
            return Err(PinMapError::SharedExti(x.function));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_receivers_pin_map_fits_the_feather() {
        assert_eq!(check(&ASSIGNMENTS, &[ADC_DRDY]), Ok(()));
    }

    #[test]
    fn pb12_is_not_on_the_header_but_is_the_sd_card_detect() {
        assert!(FEATHER_HEADER.iter().all(|(_, p)| *p != P('B', 12)));
        assert_eq!(site_pin(Site::OnBoard("SD_DETECT")), Some(P('B', 12)));
        // The map the board had before: CS on PB12 claimed as a header pin is refused.
        let mut old = ASSIGNMENTS;
        old[3] = a("antenna ADC CS", P('B', 12), Site::Header("D10"));
        assert_eq!(
            check(&old, &[ADC_DRDY]),
            Err(PinMapError::WrongPin("antenna ADC CS"))
        );
        old[3] = a("antenna ADC CS", P('B', 12), Site::Header("D32"));
        assert_eq!(
            check(&old, &[ADC_DRDY]),
            Err(PinMapError::UnknownSite("antenna ADC CS"))
        );
    }

    #[test]
    fn no_pin_serves_two_functions_and_no_exti_line_is_shared() {
        let mut m = ASSIGNMENTS;
        m[11] = a("second button", P('C', 6), Site::Header("D6"));
        assert_eq!(
            check(&m, &[ADC_DRDY]),
            Err(PinMapError::Shared("second button"))
        );
        // A second interrupt pin on line 6 next to DRDY on line 7 is fine; on line 7
        // (PB7 would be SDA, so take the mark button moved to a hypothetical PA7 = A3) not.
        let mut m = ASSIGNMENTS;
        m[8] = a("mark button", P('A', 7), Site::Header("A3"));
        assert_eq!(check(&m, &[ADC_DRDY, P('C', 6)]), Ok(()));
        assert_eq!(
            check(&m, &[ADC_DRDY, P('A', 7)]),
            Err(PinMapError::SharedExti("mark button"))
        );
    }

    #[test]
    fn the_battery_and_sd_nets_are_on_board_only() {
        assert_eq!(site_pin(Site::OnBoard("V_DIV")), Some(BATTERY));
        assert!(FEATHER_HEADER.iter().all(|(_, p)| *p != BATTERY));
        assert_eq!(site_pin(Site::Header("V_DIV")), None);
    }
}
