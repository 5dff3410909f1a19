//! The settings a base mesh was made with (SPEC §6): recorded in BASE.obj (one
//! `# dispdec-settings {json}` comment line) and in BASE.map, and used by `validate`, `bake` and
//! `reconstruct` unless a flag overrides them.

use crate::guarantee::NormalMode;
use crate::mesh::repair::Preparation;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Settings {
    pub normals: NormalMode,
    /// The largest |d| the base was made for (exact: shortest round-trip decimal).
    pub dmax: f64,
    pub strict: bool,
    /// The scan's file name (without its folder) and its face count as decimated (after
    /// welding and repair).
    pub scan: String,
    pub scan_faces: usize,
    /// How the scan was prepared: the same preparation gives the same dense mesh again.
    pub preparation: Preparation,
    /// Made with `--fine-loops` (every check walked passing loops finer): `validate` then
    /// judges the same way. Written only when true, so that other bases' settings keep their
    /// bytes (and older files read as false).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub fine_loops: bool,
}

impl Settings {
    /// The BASE.obj comment line (without the newline).
    pub fn obj_line(&self) -> String {
        format!("{}{}", crate::mesh::SETTINGS_TAG, serde_json::to_string(self).expect("settings serialise"))
    }

    pub fn parse(text: &str) -> Result<Settings, String> {
        serde_json::from_str(text).map_err(|e| format!("unreadable dispdec-settings line: {e}"))
    }
}

/// What a command will use: each value from its flag, else from the base's settings, else the
/// default; and a warning for every flag that contradicts the settings.
pub struct Resolved {
    pub normals: NormalMode,
    pub dmax: Option<f64>,
    pub strict: bool,
    pub preparation: Preparation,
    pub warnings: Vec<String>,
}

/// The flags of `validate`, `bake` and `reconstruct` that the settings can stand in for.
#[derive(Clone, Copy, Debug, Default)]
pub struct Flags {
    pub normals: Option<NormalMode>,
    pub dmax: Option<f64>,
    /// `--strict` (Some(true)) or `--no-strict` (Some(false)); None: the settings' choice.
    pub strict: Option<bool>,
    pub no_weld: bool,
    pub repair: bool,
    pub min_component: Option<usize>,
}

fn mode_name(m: NormalMode) -> &'static str {
    match m {
        NormalMode::Interpolated => "interpolated",
        NormalMode::Constant => "constant",
    }
}

/// Resolves `flags` against `settings` (those of `base`, a file name for the messages).
pub fn resolve(flags: &Flags, settings: Option<&Settings>, base: &str) -> Resolved {
    let mut warnings = Vec::new();
    let Some(s) = settings else {
        return Resolved {
            normals: flags.normals.unwrap_or(NormalMode::Interpolated),
            dmax: flags.dmax,
            strict: flags.strict.unwrap_or(false),
            preparation: Preparation {
                weld: !flags.no_weld,
                repair: flags.repair,
                min_component: flags.min_component.unwrap_or(0),
            },
            warnings,
        };
    };
    if let Some(m) = flags.normals {
        if m != s.normals {
            warnings.push(format!("{base} was made with --normals {}; using --normals {} as asked", mode_name(s.normals), mode_name(m)));
        }
    }
    if let Some(d) = flags.dmax {
        if (d - s.dmax).abs() > 1e-9 * s.dmax.abs() {
            warnings.push(format!("{base} was made with dmax {}; using --dmax {d} as asked", s.dmax));
        }
    }
    if let Some(st) = flags.strict {
        if st != s.strict {
            warnings.push(format!(
                "{base} was made {}; judging it {} as asked",
                if s.strict { "with --strict" } else { "without --strict" },
                if st { "strictly" } else { "without the uniqueness rule" }
            ));
        }
    }
    let mut prep = s.preparation;
    if flags.no_weld && prep.weld {
        warnings.push(format!("{base} was made from the welded scan; --no-weld judges another mesh"));
        prep.weld = false;
    }
    if flags.repair {
        prep.repair = true;
    }
    if let Some(m) = flags.min_component {
        if prep.repair && m != prep.min_component {
            warnings.push(format!("{base} was made with --min-component {}; using {m} as asked", prep.min_component));
        }
        prep.min_component = m;
    }
    Resolved {
        normals: flags.normals.unwrap_or(s.normals),
        dmax: Some(flags.dmax.unwrap_or(s.dmax)),
        strict: flags.strict.unwrap_or(s.strict),
        preparation: prep,
        warnings,
    }
}

/// A warning when the scan given is not the one the base was made from (by face count).
pub fn scan_mismatch(settings: Option<&Settings>, base: &str, high: &str, high_faces: usize) -> Option<String> {
    let s = settings?;
    (s.scan_faces != high_faces).then(|| {
        format!("{base} was made from {} ({} faces as decimated); {high} has {high_faces}", s.scan, s.scan_faces)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn made() -> Settings {
        Settings {
            normals: NormalMode::Constant,
            dmax: 0.123456789012345,
            strict: true,
            scan: "bunny.ply.gz".into(),
            scan_faces: 69451,
            preparation: Preparation { weld: true, repair: true, min_component: 10 },
            fine_loops: true,
        }
    }

    /// A base made without `--fine-loops` writes no `fine_loops` key (its settings keep the
    /// bytes of the release before), and settings without one read as false.
    #[test]
    fn fine_loops_is_written_only_when_on() {
        let mut s = made();
        s.fine_loops = false;
        let line = s.obj_line();
        assert!(!line.contains("fine_loops"), "{line}");
        assert_eq!(Settings::parse(line.strip_prefix(crate::mesh::SETTINGS_TAG).unwrap()).unwrap(), s);
        s.fine_loops = true;
        assert!(s.obj_line().contains("\"fine_loops\":true"), "{}", s.obj_line());
    }

    #[test]
    fn settings_round_trip_exactly() {
        let s = made();
        let line = s.obj_line();
        let back = Settings::parse(line.strip_prefix(crate::mesh::SETTINGS_TAG).unwrap()).unwrap();
        assert_eq!(back, s);
    }

    #[test]
    fn flags_override_settings_and_warn() {
        let s = made();
        let r = resolve(&Flags::default(), Some(&s), "base.obj");
        assert_eq!((r.normals, r.dmax, r.strict), (NormalMode::Constant, Some(s.dmax), true));
        assert_eq!(r.preparation, s.preparation);
        assert!(r.warnings.is_empty());
        let f = Flags { normals: Some(NormalMode::Interpolated), dmax: Some(0.2), ..Default::default() };
        let r = resolve(&f, Some(&s), "base.obj");
        assert_eq!((r.normals, r.dmax), (NormalMode::Interpolated, Some(0.2)));
        assert_eq!(r.warnings.len(), 2, "{:?}", r.warnings);
        assert!(r.warnings[0].contains("--normals constant"));
        // Without settings: the flags, else the defaults, and no warning.
        let r = resolve(&Flags::default(), None, "x.obj");
        assert_eq!((r.normals, r.dmax, r.strict), (NormalMode::Interpolated, None, false));
        assert_eq!(r.preparation, Preparation::default());
    }
}
