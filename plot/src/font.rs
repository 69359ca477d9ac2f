//! Finds a TrueType font at run time and registers it with plotters (ab_glyph), once.
//!
//! No font is embedded in the crate; Debian's `fonts-dejavu-core` (installed by
//! `scripts/setup.sh`) provides the default one.

use std::path::PathBuf;
use std::sync::OnceLock;

use ab_glyph::FontRef;
use plotters::style::{register_font, FontStyle};

/// Where to look, in order; `$ABVS_FONT` comes first.
const SYSTEM_FONTS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
];

/// The font, or why there is none; decided on first use.
static FONT: OnceLock<Result<FontRef<'static>, String>> = OnceLock::new();

/// The font for plot text, `None` if there is none (plots are then drawn without text). The
/// first call loads and registers it, and logs a warning (once per process) if there is none.
pub(crate) fn font() -> Option<&'static FontRef<'static>> {
    FONT.get_or_init(|| {
        let r = load();
        if let Err(w) = &r {
            log::warn!("abvs-plot: {w}");
        }
        r
    })
    .as_ref()
    .ok()
}

/// Why plots are drawn without text, if they are (`None` when a font is in use). Loads the
/// font if no plot was drawn yet, so callers can report the problem up front.
pub fn font_warning() -> Option<&'static str> {
    font();
    FONT.get().and_then(|r| r.as_ref().err()).map(String::as_str)
}

fn load() -> Result<FontRef<'static>, String> {
    let env = std::env::var_os("ABVS_FONT").filter(|v| !v.is_empty()).map(PathBuf::from);
    let candidates = env.into_iter().chain(SYSTEM_FONTS.iter().map(PathBuf::from));
    let mut tried = Vec::new();
    for path in candidates {
        if !path.is_file() {
            tried.push(path.display().to_string());
            continue;
        }
        match std::fs::read(&path) {
            Ok(bytes) if FontRef::try_from_slice(&bytes).is_ok() => {
                // plotters keeps `&'static [u8]`: leaked once, for the one font that is used.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                let font = FontRef::try_from_slice(bytes).expect("parsed just above");
                // Our canvas draws the text itself (see `canvas`); registering with plotters
                // too keeps any of its own text paths working.
                if register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return Ok(font);
                }
                tried.push(format!("{} (rejected by plotters)", path.display()));
            }
            Ok(_) => tried.push(format!("{} (not a usable TrueType font)", path.display())),
            Err(e) => tried.push(format!("{} ({e})", path.display())),
        }
    }
    Err(format!(
        "no font found, plots are drawn without text (set ABVS_FONT to a .ttf file or install \
         fonts-dejavu-core); tried: {}",
        tried.join(", ")
    ))
}
