//! The controllers' settings check themselves: the study's defaults pass, and every bad
//! value is named by its sub-table and key.

use jetbench_control::{ControlError, LawSettings};

/// The sub-table, the key, and how to spoil it.
type Case = (&'static str, &'static str, fn(&mut LawSettings));

#[test]
fn the_default_settings_are_valid() {
    assert_eq!(LawSettings::default().validate(), Ok(()));
}

#[test]
fn each_bad_setting_is_named_by_its_table_and_key() {
    let cases: [Case; 10] = [
        ("fbl", "kp", |s| s.fbl.kp = 0.0),
        ("fbl", "kd", |s| s.fbl.kd = f64::NAN),
        ("fbl", "ki", |s| s.fbl.ki = -0.1),
        ("smc", "a1", |s| s.smc.a1 = f64::INFINITY),
        ("smc", "k", |s| s.smc.k = -1.0),
        ("smc", "beta", |s| s.smc.beta = f64::NAN),
        ("shaping", "authority", |s| s.shaping.authority = 0.0),
        ("shaping", "bandwidth_rad_per_s", |s| s.shaping.bandwidth_rad_per_s = 0.0),
        ("mpc", "integral_rad_per_s", |s| s.mpc.integral_rad_per_s = -0.1),
        ("mpc", "integral_rad_per_s", |s| s.mpc.integral_rad_per_s = s.mpc.correction_rad_per_s + 0.1),
    ];
    for (table, key, spoil) in cases {
        let mut settings = LawSettings::default();
        spoil(&mut settings);
        let e = settings.validate().expect_err("a spoiled setting is refused");
        assert_eq!(e.table, table);
        match e.error {
            ControlError::SettingOutOfRange { name, .. } => assert_eq!(name, key),
            other => panic!("{table}.{key}: unexpected {other:?}"),
        }
        assert!(e.to_string().starts_with(&format!("[control.{table}] controller setting {key} = ")), "{e}");
    }
    // Zero integral gains and zero switching amplitude are legitimate laws.
    let mut settings = LawSettings::default();
    settings.fbl.ki = 0.0;
    settings.smc.beta = 0.0;
    settings.mpc.integral_rad_per_s = 0.0;
    assert_eq!(settings.validate(), Ok(()));
}
