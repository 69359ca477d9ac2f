pub mod board;
pub mod detector;
pub mod image_util;
pub mod math_util;
pub mod saddle;
pub mod tag_families;

pub use tag_families::TagFamily;
