//! The antenna's receive path as the board runs it: the emulated ADS131M04 (with its
//! input noise) and IF range switch, the firmware's driver and pulse DSP, and the glue the
//! board binary has between them — every conversion pushed to the DSP, every
//! [`RangeChange`] the DSP asks for applied (one `GAIN1` write for the three coils, the
//! range switch's GPIO) before the next conversion is read.
use super::ads131m04::{Ads131m04Drdy, Ads131m04Spi, ads131m04};
use super::if_signal::{AnalogInput, RangeSwitch};
use super::{NoDelay, SimClock};
use anyhow::{Result, anyhow};
use embedded_hal::digital::OutputPin;
use firmware::board::REFERENCE;
use firmware::drivers::ads131m04::{Ads131m04, Config, Error as AdcError};
use firmware::frontend::{Frontend, FrontendConfig, IfRange, Pulse, Range, RangeChange};

/// The emulated ADC behind the firmware's driver.
pub type EmulatedAdc<A> = Ads131m04<Ads131m04Spi<A>, Ads131m04Drdy<A>>;

/// ADC, range switch and DSP of one emulated unit.
#[derive(Debug)]
pub struct Antenna<A: AnalogInput> {
    /// The firmware's ADC driver on the emulated chip.
    pub adc: EmulatedAdc<A>,
    /// The IF range switch (shared with the signal source).
    pub switch: RangeSwitch,
    /// The firmware's pulse DSP.
    pub frontend: Frontend,
    /// Every change of the analog setting, in order.
    pub changes: Vec<RangeChange>,
    /// Conversions read.
    pub samples: u64,
}

/// Sets the hardware to `range`: the coils' PGA gain in one register write, then the
/// switch's pin (high = low range).
pub fn apply_range<A: AnalogInput>(
    adc: &mut EmulatedAdc<A>,
    switch: &mut RangeSwitch,
    range: Range,
) -> Result<()> {
    adc.set_coil_gains(range.gain)
        .map_err(|e| anyhow!("ADC gain write: {e:?}"))?;
    let pin = match range.if_range {
        IfRange::High => switch.set_low(),
        IfRange::Low => switch.set_high(),
    };
    pin.map_err(|e| anyhow!("range switch: {e:?}"))
}

impl<A: AnalogInput> Antenna<A> {
    /// [`Antenna::new`] with the reference board's ADC configuration on a fresh clock at 0,
    /// which is returned beside it (the caller steps it).
    pub fn on_reference_board(
        input: A,
        switch: RangeSwitch,
        fe_cfg: FrontendConfig,
        noise_seed: u64,
    ) -> Result<(Self, SimClock)> {
        let clock = SimClock::new();
        let antenna = Self::new(
            input,
            switch,
            clock.clone(),
            &REFERENCE.adc.config,
            fe_cfg,
            noise_seed,
        )?;
        Ok((antenna, clock))
    }

    /// Powers up the emulated ADC converting `input` (whose range switch is `switch`) on
    /// `clock` with the reference board's input noise (drawn from `noise_seed`), resets
    /// and configures it with `adc_cfg`, and sets it to the DSP's starting setting.
    pub fn new(
        input: A,
        switch: RangeSwitch,
        clock: SimClock,
        adc_cfg: &Config,
        fe_cfg: FrontendConfig,
        noise_seed: u64,
    ) -> Result<Self> {
        let (spi, drdy) = ads131m04(input, clock);
        spi.set_input_noise(REFERENCE.adc.input_noise_v_rms, noise_seed);
        let mut adc = Ads131m04::new(spi, drdy);
        adc.reset(&mut NoDelay)
            .map_err(|e| anyhow!("ADC reset: {e:?}"))?;
        adc.check_id().map_err(|e| anyhow!("ADC id: {e:?}"))?;
        adc.configure(adc_cfg)
            .map_err(|e| anyhow!("ADC configure: {e:?}"))?;
        adc.set_drdy_poll_limit(1);
        let frontend =
            Frontend::new(fe_cfg).map_err(|e| anyhow!("frontend configuration: {e:?}"))?;
        let mut switch = switch;
        apply_range(&mut adc, &mut switch, frontend.range())?;
        Ok(Self {
            adc,
            switch,
            frontend,
            changes: Vec::new(),
            samples: 0,
        })
    }

    /// Reads every conversion ready at the clock's time into the DSP, applying the
    /// setting changes it asks for; `on_pulse` gets each pulse.
    pub fn drain(&mut self, mut on_pulse: impl FnMut(Pulse)) -> Result<()> {
        loop {
            let frame = match self.adc.read_frame_when_ready() {
                Ok(f) => f,
                Err(AdcError::Timeout) => return Ok(()),
                Err(e) => return Err(anyhow!("ADC read: {e:?}")),
            };
            self.samples += 1;
            let v = self.adc.to_volts(&frame);
            let p = self
                .frontend
                .push([v[0], v[1], v[2]], frame.coils_saturated())
                .map_err(|e| anyhow!("frontend: {e:?}"))?;
            if let Some(c) = self.frontend.take_range_change() {
                apply_range(&mut self.adc, &mut self.switch, c.to)?;
                self.changes.push(c);
            }
            if let Some(p) = p {
                on_pulse(p);
            }
        }
    }
}
