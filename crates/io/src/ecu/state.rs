//! The ECU's states and off conditions, named, with JetCat's numbers.
//!
//! Two numberings exist in JetCat's published material, and both are kept:
//! - the RS232 interface's: the state code in the `RAC` reply (0 off, 1
//!   standby, 2 ignite, ... 11 run) and the off condition in the `RSS` reply
//!   (0 none, 1 R/C off, 2 over-temperature, ... 8 low battery, 14 fail-safe);
//! - the telemetry numbering JetCat's ECU hands to telemetry converters, one
//!   signed value for both: the state while there is no off condition (0 off,
//!   1 slow-down, 3 standby, ... 13 run), otherwise the off condition as a
//!   negative code (-6 over-RPM, -7 low RPM, -8 low battery, -9
//!   over-temperature, -14 fail-safe, ...).
//!
//! [`EcuState::code`] and [`OffCondition::code`] are the RS232 numbers (what
//! the codec reads and writes); [`EcuState::telemetry_code`] and
//! [`OffCondition::telemetry_code`] the signed ones. Every value has a name
//! ([`fmt::Display`]); codes outside the tables decode to `None`, never panic.
//!
//! ```
//! use jetbench_io::ecu::state::{EcuState, OffCondition};
//!
//! assert_eq!(EcuState::from_code(11), Some(EcuState::Run));
//! assert_eq!(EcuState::Run.to_string(), "run");
//! assert_eq!(EcuState::Run.telemetry_code(), 13);
//! assert_eq!(OffCondition::from_code(2), Some(OffCondition::OverTemperature));
//! assert_eq!(OffCondition::OverTemperature.telemetry_code(), -9);
//! assert_eq!(OffCondition::from_telemetry_code(-9), Some(OffCondition::OverTemperature));
//! assert!(OffCondition::OverTemperature.is_fault() && !OffCondition::ManualOff.is_fault());
//! ```

use std::fmt;

macro_rules! coded_enum {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[$vmeta:meta])* $variant:ident = $code:literal, $telemetry:literal, $text:literal; )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name {
            $( $(#[$vmeta])* $variant = $code, )*
        }

        impl $name {
            /// Every value, in code order.
            pub const ALL: &'static [$name] = &[$($name::$variant),*];

            /// The RS232 interface's number.
            pub fn code(self) -> u8 {
                self as u8
            }

            /// The value with RS232 number `code`, if there is one.
            pub fn from_code(code: u32) -> Option<Self> {
                match code {
                    $( $code => Some($name::$variant), )*
                    _ => None,
                }
            }

            /// The signed number of JetCat's telemetry numbering.
            pub fn telemetry_code(self) -> i32 {
                match self {
                    $( $name::$variant => $telemetry, )*
                }
            }

            /// The value with telemetry number `code`, if there is one.
            pub fn from_telemetry_code(code: i32) -> Option<Self> {
                Self::ALL.iter().copied().find(|v| v.telemetry_code() == code)
            }

            /// The name, lower case, words separated by spaces.
            pub fn name(self) -> &'static str {
                match self {
                    $( $name::$variant => $text, )*
                }
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.name())
            }
        }
    };
}

coded_enum! {
    /// What the ECU is doing: the state field of the `RAC` reply.
    pub enum EcuState {
        /// Off: nothing runs, a start is refused until standby.
        Off = 0, 0, "off";
        /// Standby ("wait for RPM", Stby/Start): ready, waiting for a start.
        Standby = 1, 3, "standby";
        /// The starter spins the rotor, the glow plug lights the gas.
        Ignite = 2, 6, "ignite";
        /// Fuel flows, the rotor accelerates towards idle.
        Accelerate = 3, 10, "accelerate";
        /// At idle, the temperatures settle before control is handed over.
        Stabilise = 4, 11, "stabilise";
        /// Learning the idle pump setting.
        LearnLow = 6, 12, "learn low";
        /// Learning the full-throttle pump setting (the telemetry numbering has
        /// one learn state, 12, which reads back as learn low).
        LearnHigh = 5, 12, "learn high";
        /// Slow-down: fuel off, the starter cools the engine until the exhaust is cold.
        SlowDown = 8, 1, "slow-down";
        /// Auto-off: a commanded shutdown in progress.
        AutoOff = 10, 2, "auto-off";
        /// Running, thrust follows the throttle.
        Run = 11, 13, "run";
        /// A short pause before acceleration in the start sequence.
        AccelerationDelay = 12, 7, "acceleration delay";
        /// Running under the ECU's own speed control.
        SpeedControl = 13, 14, "speed control";
        /// Running, regulating a second shaft.
        TwoShaftRegulate = 14, 15, "two-shaft regulate";
        /// Kerosene start: first preheat stage.
        Preheat1 = 15, 4, "preheat 1";
        /// Kerosene start: second preheat stage.
        Preheat2 = 16, 5, "preheat 2";
        /// Kerosene start: the main fuel is started.
        MainFuelStart = 17, 8, "main fuel start";
        /// Kerosene start: the fuel is ramped to full flow for the start.
        KeroseneFullOn = 19, 9, "kerosene full on";
    }
}

coded_enum! {
    /// Why the engine stopped: the off condition of the `RSS` reply.
    pub enum OffCondition {
        /// No off condition recorded.
        None = 0, 0, "none";
        /// Shut down from the radio (AUX switch or throttle trim).
        RcOff = 1, -1, "shut down via R/C";
        /// The exhaust stayed above the high-temperature limit past its time-out.
        OverTemperature = 2, -9, "over-temperature";
        /// No ignition within the programmed time.
        IgnitionTimeout = 3, -15, "ignition time-out";
        /// Ignited but did not accelerate within the programmed time.
        AccelerationTimeout = 4, -4, "acceleration time-out";
        /// Accelerated more slowly than programmed during the start.
        AccelerationTooSlow = 5, -5, "acceleration too slow";
        /// Above the maximum RPM by 5 % for 0.5 s.
        OverRpm = 6, -6, "over-RPM";
        /// Below the minimum RPM by 10 % for 3 s: usually a flame-out.
        LowRpm = 7, -7, "low RPM (flame-out)";
        /// The ECU's battery is exhausted.
        LowBattery = 8, -8, "low battery";
        /// Shut down through the auto-off sequence.
        AutoOff = 9, -2, "auto-off";
        /// The exhaust temperature fell below its minimum (flame-out or a loose sensor).
        LowTemperature = 10, -10, "low temperature";
        /// The exhaust temperature left the sensor's range (about 950 °C).
        HighTemperature = 11, -11, "high temperature";
        /// The glow plug is defective.
        GlowPlug = 12, -12, "glow plug defective";
        /// The ECU's watchdog reset it.
        Watchdog = 13, -13, "watchdog";
        /// The throttle signal was lost for longer than the fail-safe time.
        FailSafe = 14, -14, "fail-safe";
        /// Shut down by the operator through the ground unit or the serial interface.
        ManualOff = 15, -3, "manual off";
        /// The ECU lost power while the engine ran.
        PowerFail = 16, -16, "power fail";
        /// The exhaust temperature sensor failed (seen during the start).
        TempSensorFail = 17, -17, "temperature sensor failed";
        /// Fuel supply failure.
        FuelFail = 18, -18, "fuel fail";
        /// Second-shaft (propeller) failure.
        PropFail = 19, -19, "propeller fail";
        /// The second engine of a pair failed.
        SecondEngineFail = 20, -20, "second engine failed";
        /// The two engines of a pair differ too much.
        SecondEngineDifference = 21, -21, "second engine difference too high";
        /// No communication with the second engine of a pair.
        SecondEngineSilent = 22, -22, "second engine not communicating";
    }
}

impl EcuState {
    /// Running: thrust follows the throttle.
    pub fn is_running(self) -> bool {
        matches!(self, EcuState::Run | EcuState::SpeedControl | EcuState::TwoShaftRegulate)
    }

    /// In the start sequence, between the start command and run.
    pub fn is_starting(self) -> bool {
        matches!(
            self,
            EcuState::Ignite
                | EcuState::Preheat1
                | EcuState::Preheat2
                | EcuState::MainFuelStart
                | EcuState::KeroseneFullOn
                | EcuState::AccelerationDelay
                | EcuState::Accelerate
                | EcuState::Stabilise
                | EcuState::LearnHigh
                | EcuState::LearnLow
        )
    }

    /// Burning fuel: starting or running.
    pub fn is_burning(self) -> bool {
        self.is_starting() || self.is_running()
    }

    /// Stopping: the fuel is off and the engine cools down.
    pub fn is_stopping(self) -> bool {
        matches!(self, EcuState::SlowDown | EcuState::AutoOff)
    }
}

impl OffCondition {
    /// A shutdown the ECU made on its own (not the operator's or the radio's).
    pub fn is_fault(self) -> bool {
        !matches!(self, OffCondition::None | OffCondition::RcOff | OffCondition::AutoOff | OffCondition::ManualOff)
    }
}

/// The one signed value of JetCat's telemetry numbering: the off condition
/// (negative) while the engine is stopping or off after one, else the state.
pub fn telemetry_status(state: EcuState, off: OffCondition) -> i32 {
    if off != OffCondition::None && !state.is_burning() {
        off.telemetry_code()
    } else {
        state.telemetry_code()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_names_are_distinct() {
        for s in EcuState::ALL {
            assert_eq!(EcuState::from_code(u32::from(s.code())), Some(*s));
        }
        for o in OffCondition::ALL {
            assert_eq!(OffCondition::from_code(u32::from(o.code())), Some(*o));
            assert_eq!(OffCondition::from_telemetry_code(o.telemetry_code()), Some(*o));
            assert!(o.telemetry_code() <= 0);
        }
        let mut names: Vec<_> = EcuState::ALL.iter().map(|s| s.name()).collect();
        names.extend(OffCondition::ALL.iter().map(|o| o.name()));
        let n = names.len();
        names.sort_unstable();
        names.dedup();
        // "auto-off" is both a state and an off condition, as in JetCat's tables.
        assert_eq!(names.len(), n - 1);
        for code in [7, 9, 18, 20, 255, u32::MAX] {
            assert_eq!(EcuState::from_code(code), None, "{code}");
        }
        assert_eq!(OffCondition::from_code(23), None);
        assert_eq!(OffCondition::from_telemetry_code(-99), None);
    }

    #[test]
    fn the_telemetry_status_is_the_off_condition_once_the_fuel_is_off() {
        assert_eq!(telemetry_status(EcuState::Run, OffCondition::None), 13);
        assert_eq!(telemetry_status(EcuState::SlowDown, OffCondition::None), 1);
        assert_eq!(telemetry_status(EcuState::SlowDown, OffCondition::LowBattery), -8);
        assert_eq!(telemetry_status(EcuState::Off, OffCondition::OverRpm), -6);
        // A new start clears what the last run left.
        assert_eq!(telemetry_status(EcuState::Ignite, OffCondition::OverRpm), 6);
    }
}
