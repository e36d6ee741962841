//! The bundled font: DejaVu Sans, so that plots render the same everywhere without system font
//! libraries (fontconfig, freetype).
//!
//! The font file and its license (Bitstream Vera / DejaVu, permissive) live in
//! `pbdl-core/assets/`. [`register_fonts`] makes it plotters' `"sans-serif"` family (and also
//! `"serif"`, `"monospace"` and `"DejaVu Sans"`, so that no family name falls through); the plot
//! functions call it themselves.

use crate::error::{Error, Result};
use plotters::style::FontStyle;
use plotters_backend::{BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingBackend, DrawingErrorKind};
use std::sync::OnceLock;

/// The family name plots use.
pub const FONT_FAMILY: &str = "sans-serif";

/// DejaVu Sans (regular), as shipped in `pbdl-core/assets/DejaVuSans.ttf`.
pub static DEJAVU_SANS: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// The DejaVu font license text, to ship with anything that redistributes the font.
pub static DEJAVU_LICENSE: &str = include_str!("../../assets/DejaVuSans-LICENSE.txt");

/// Registers [`DEJAVU_SANS`] with plotters, once per process; later calls are free.
pub fn register_fonts() -> Result<()> {
    static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        for family in [FONT_FAMILY, "serif", "monospace", "DejaVu Sans"] {
            // Bold and italic requests fall back to the regular face inside plotters.
            plotters::style::register_font(family, FontStyle::Normal, DEJAVU_SANS)
                .map_err(|_| format!("the bundled font could not be parsed as `{family}`"))?;
        }
        Ok(())
    })
    .clone()
    .map_err(|reason| Error::invalid("register_fonts", "DEJAVU_SANS", reason))
}

/// A drawing backend that draws text itself, with the bundled font, and delegates everything
/// else to `DB`.
///
/// plotters' own ab_glyph text path places each glyph at the pen position without its left
/// side bearing, so letter gaps come out uneven ("rn" reads as "m"). This one lays out glyphs
/// as the font says: advance, kerning, bearings, and the font's ascent and descent for the box.
pub(crate) struct GlyphBackend<DB>(pub DB);

fn scaled_font(size: f64) -> ab_glyph::PxScaleFont<&'static ab_glyph::FontRef<'static>> {
    use ab_glyph::Font;
    static FONT: OnceLock<ab_glyph::FontRef<'static>> = OnceLock::new();
    let font = FONT.get_or_init(|| ab_glyph::FontRef::try_from_slice(DEJAVU_SANS).expect("the bundled font parses"));
    font.as_scaled(size as f32)
}

/// Width and height of `text`'s box, and the pen x of every glyph.
fn layout(text: &str, size: f64) -> (u32, u32, Vec<(ab_glyph::GlyphId, f32)>) {
    use ab_glyph::ScaleFont;
    let font = scaled_font(size);
    let mut pen = 0f32;
    let mut prev = None;
    let mut glyphs = Vec::with_capacity(text.len());
    for c in text.chars() {
        let id = font.glyph_id(c);
        if let Some(p) = prev {
            pen += font.kern(p, id);
        }
        glyphs.push((id, pen));
        pen += font.h_advance(id);
        prev = Some(id);
    }
    (pen.ceil().max(0.0) as u32, (font.ascent() - font.descent()).ceil() as u32, glyphs)
}

impl<DB: DrawingBackend> DrawingBackend for GlyphBackend<DB> {
    type ErrorType = DB::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.0.get_size()
    }

    fn ensure_prepared(&mut self) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.ensure_prepared()
    }

    fn present(&mut self) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.present()
    }

    fn draw_pixel(
        &mut self,
        point: BackendCoord,
        color: BackendColor,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.draw_pixel(point, color)
    }

    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.draw_line(from, to, style)
    }

    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.draw_rect(upper_left, bottom_right, style, fill)
    }

    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.draw_path(path, style)
    }

    fn draw_circle<S: BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.draw_circle(center, radius, style, fill)
    }

    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.fill_polygon(vert, style)
    }

    fn blit_bitmap(
        &mut self,
        pos: BackendCoord,
        size: (u32, u32),
        src: &[u8],
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.0.blit_bitmap(pos, size, src)
    }

    fn estimate_text_size<TStyle: BackendTextStyle>(
        &self,
        text: &str,
        style: &TStyle,
    ) -> std::result::Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        let (w, h, _) = layout(text, style.size());
        Ok((w, h))
    }

    fn draw_text<TStyle: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &TStyle,
        pos: BackendCoord,
    ) -> std::result::Result<(), DrawingErrorKind<Self::ErrorType>> {
        use ab_glyph::{Font, ScaleFont};
        use plotters_backend::text_anchor::{HPos, VPos};
        let color = style.color();
        if color.alpha == 0.0 {
            return Ok(());
        }
        let size = style.size();
        let font = scaled_font(size);
        let (w, h, glyphs) = layout(text, size);
        // Offset of the box's top-left corner from the anchor, before rotation.
        let dx = match style.anchor().h_pos {
            HPos::Left => 0,
            HPos::Right => -(w as i32),
            HPos::Center => -(w as i32) / 2,
        };
        let dy = match style.anchor().v_pos {
            VPos::Top => 0,
            VPos::Center => -(h as i32) / 2,
            VPos::Bottom => -(h as i32),
        };
        let transform = style.transform();
        let (width, height) = self.get_size();
        let ascent = font.ascent();
        for (id, pen) in glyphs {
            let glyph = id.with_scale_and_position(font.scale(), ab_glyph::point(pen, ascent));
            let Some(outline) = font.font().outline_glyph(glyph) else { continue };
            let bounds = outline.px_bounds();
            let mut pixels = Vec::new();
            outline.draw(|x, y, coverage| {
                pixels.push((x as i32 + bounds.min.x as i32, y as i32 + bounds.min.y as i32, coverage))
            });
            for (x, y, coverage) in pixels {
                if coverage <= 0.0 {
                    continue;
                }
                let (x, y) = transform.transform(x + dx, y + dy);
                let (x, y) = (pos.0 + x, pos.1 + y);
                if x >= 0 && y >= 0 && (x as u32) < width && (y as u32) < height {
                    let alpha = color.alpha * coverage.min(1.0) as f64;
                    self.0.draw_pixel((x, y), BackendColor { alpha, rgb: color.rgb })?;
                }
            }
        }
        Ok(())
    }
}
