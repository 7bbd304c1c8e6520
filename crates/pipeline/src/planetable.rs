//! The plane table between sender and receiver: the sender quantises the
//! plane matcher's planes (fitted over the transmitted left labels) into
//! the frame's [`PlaneTable`]; the receiver rebuilds the dense map from
//! the labels it decoded and the table ([`rebuild_coded_into`]: the table's
//! indices decode against those labels' segments), in integers, without
//! matching. Both fill the map the same way, so they hold the very same map.

use stereolink_codec::planetable::{CodedPlaneTable, PlaneTable, TableCoding, FRACTION_BITS};
use stereolink_codec::CodecError;
use stereolink_image::segments::components;
use stereolink_image::{DisparityMap, LabelMap, Plane};
use stereolink_stereo::planes::PlaneMap;
use stereolink_stereo::MatchSpec;

/// The plane table of `matched` (matched over the segments of the
/// transmitted left labels with `spec`), coded as `coding` says.
///
/// # Errors
/// If the tile side or the disparity range do not fit the wire's 16 bits.
pub fn table_of(
    matched: &PlaneMap,
    spec: &MatchSpec,
    coding: TableCoding,
) -> anyhow::Result<PlaneTable> {
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
    let ids = Some(&matched.graph.ids);
    Ok(PlaneTable::quantise(tile, (lo, hi), coding, ids, &planes))
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
    let (ids, segments) = components(labels, table.tile as usize);
    table.check_segments(segments)?;
    fill(&ids, table, out);
    Ok(())
}

/// The receiver's [`rebuild_into`]: decodes a frame's table against the
/// segments of the left `labels` it decoded, then rebuilds.
///
/// # Errors
/// If the table does not belong to these labels or does not decode.
pub fn rebuild_coded_into(
    labels: &LabelMap,
    coded: &CodedPlaneTable,
    out: &mut DisparityMap,
) -> Result<(), CodecError> {
    let (ids, segments) = components(labels, coded.tile() as usize);
    fill(&ids, &coded.resolve(&ids, segments)?, out);
    Ok(())
}

/// Each pixel of `ids` its segment's plane of `table`.
fn fill(ids: &Plane<u32>, table: &PlaneTable, out: &mut DisparityMap) {
    let (w, h) = ids.dims();
    out.reset(w, h, f32::INFINITY);
    let scale = 1.0 / (1u32 << FRACTION_BITS) as f32;
    for (p, (&s, d)) in ids.as_slice().iter().zip(out.as_mut_slice()).enumerate() {
        if let Some(fixed) = table.disparity(s as usize, p % w, p / w) {
            *d = fixed as f32 * scale;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::receiver::{BoardReceiver, DisparitySource, Event};
    use stereolink_codec::{container, Message, SegmentationKind, StereoFrame, View};
    use stereolink_image::IndexedImage;

    /// Label 0 left of x = 4, label 1 right of it; in tiles of 4 px the
    /// segments are 0 (x < 4), 1 (x 4..8) and 2 (x 8..12, cut by the tile).
    fn labels() -> LabelMap {
        LabelMap::from_fn(12, 3, |x, _| u16::from(x >= 4))
    }

    #[test]
    fn rebuilds_each_segments_plane_exactly_and_checks_the_count() {
        let planes = [[0.5, 0.0, 1.0], [0.0, 0.25, 7.0], [-1.0, 0.0, 20.0]];
        let table = PlaneTable::quantise(4, (0, 15), TableCoding::EXACT, None, &planes);
        let mut out = DisparityMap::default();
        rebuild_into(&labels(), &table, &mut out).unwrap();
        for (x, y) in [(0, 0), (3, 2), (5, 1), (9, 2), (11, 0)] {
            let [a, b, c] = planes[x / 4];
            let want = (a * x as f32 + b * y as f32 + c).clamp(0.0, 15.0);
            assert_eq!(out.get(x, y), want, "({x}, {y})");
        }
        // Without tiles the labels have two segments, not three.
        let untiled = PlaneTable { tile: 0, ..table };
        assert!(rebuild_into(&labels(), &untiled, &mut out).is_err());
        // No plane at all: invalid everywhere.
        rebuild_into(&labels(), &PlaneTable::default(), &mut out).unwrap();
        assert!(out.as_slice().iter().all(|d| d.is_infinite()));
    }

    #[test]
    fn a_board_on_planes_rejects_a_frame_without_a_table_or_of_other_labels() {
        let view = || View::Indexed(IndexedImage::new(labels(), vec![[0; 3], [9; 3]]).unwrap());
        let frame = |planes| StereoFrame {
            kind: SegmentationKind::KMeans,
            levels: 2,
            params: String::new(),
            thresholds: None,
            calibration: None,
            left: view(),
            right: view(),
            planes,
        };
        let mut board = BoardReceiver::new(3, 3, std::time::Duration::from_secs(1));
        board.source = DisparitySource::Planes;
        let quantise = |planes: &[[f32; 3]]| {
            PlaneTable::quantise(0, (0, 3), TableCoding::default(), None, planes)
        };
        let two = quantise(&[[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]);
        let five = quantise(&[[0.0, 0.0, 1.0]; 5]);
        for (planes, shown) in [(None, false), (Some(five), false), (Some(two), true)] {
            let bytes = container::encode(&Message::StereoFrame(Box::new(frame(planes))), 1, 0);
            let event = board.handle(&bytes);
            assert_eq!(matches!(event, Event::Frame { .. }), shown, "{event:?}");
        }
        assert_eq!(board.disparity().get(11, 2), 2.0);
    }
}
