//! The plane table between sender and receiver: the sender quantises the
//! plane matcher's planes (fitted over the transmitted left labels) into
//! the frame's [`PlaneTable`]; the receiver rebuilds the dense map from
//! the labels it decoded and the table, in integers, without matching.
//! Both rebuild with [`rebuild_into`], so they hold the very same map.

use stereolink_codec::planetable::{PlaneTable, FRACTION_BITS};
use stereolink_codec::CodecError;
use stereolink_image::{DisparityMap, LabelMap};
use stereolink_stereo::planes::{graph, PlaneMap};
use stereolink_stereo::MatchSpec;

/// The plane table of `matched` (matched over the segments of the
/// transmitted left labels with `spec`).
///
/// # Errors
/// If the tile side or the disparity range do not fit the wire's 16 bits.
pub fn table_of(matched: &PlaneMap, spec: &MatchSpec) -> anyhow::Result<PlaneTable> {
    let tile = u16::try_from(spec.planes.tile)
        .map_err(|_| anyhow::anyhow!("plane tile {} exceeds 65535", spec.planes.tile))?;
    let range = (i16::try_from(spec.min_disp), i16::try_from(spec.max_disp));
    let (Ok(lo), Ok(hi)) = range else {
        anyhow::bail!(
            "disparity range {}..{} exceeds the plane table's 16 bits",
            spec.min_disp,
            spec.max_disp
        );
    };
    let planes: Vec<[f32; 3]> = matched.planes.iter().map(|p| [p.a, p.b, p.c]).collect();
    Ok(PlaneTable::quantise(tile, (lo, hi), &planes))
}

/// Rebuilds the dense map of `table` over the segments of `labels` into
/// `out`: each pixel its segment's plane in 16.16 fixed point, then in px
/// (invalid everywhere when the table has no plane).
///
/// # Errors
/// If the table's segment count is not the labels' (the table belongs to
/// another label map).
pub fn rebuild_into(
    labels: &LabelMap,
    table: &PlaneTable,
    out: &mut DisparityMap,
) -> Result<(), CodecError> {
    let (ids, segments) = graph::components(labels, table.tile as usize);
    table.check_segments(segments)?;
    let (w, h) = labels.dims();
    out.reset(w, h, f32::INFINITY);
    let scale = 1.0 / (1u32 << FRACTION_BITS) as f32;
    for (p, (&s, d)) in ids.as_slice().iter().zip(out.as_mut_slice()).enumerate() {
        if let Some(fixed) = table.disparity(s as usize, p % w, p / w) {
            *d = fixed as f32 * scale;
        }
    }
    Ok(())
}
