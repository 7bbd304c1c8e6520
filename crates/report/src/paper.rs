//! The paper's published figures, kept as data so the report can print them
//! beside ours: Table IV (PSNR of the segmented images, dB), Tables V and VI
//! (depth levels found with WTA and with line growing), and the 95 %
//! confidence intervals of the size reduction (Fig. 12).

/// Methods in the paper's column order.
pub const METHODS: [&str; 5] = ["meanshift", "kmeans", "pso", "dpso", "fodpso"];

/// Table IV: PSNR (dB) per scene, columns [`METHODS`].
pub const TABLE_IV: [(&str, [f64; 5]); 10] = [
    ("tsukuba", [20.47, 10.0, 14.42, 15.0, 17.08]),
    ("art", [14.54, 8.0, 13.0, 16.0, 16.0]),
    ("books", [16.81, 6.31, 13.99, 14.39, 13.04]),
    ("cones", [16.26, 8.0, 16.26, 14.5, 15.47]),
    ("dolls", [14.0, 8.34, 16.0, 13.0, 16.0]),
    ("laundry", [14.89, 5.74, 16.83, 16.72, 14.77]),
    ("moebius", [18.44, 6.44, 16.75, 15.61, 15.6]),
    ("reindeer", [18.44, 10.2, 18.046, 15.12, 14.45]),
    ("teddy", [18.22, 7.41, 18.6, 17.51, 11.0]),
    ("venus", [17.11, 10.0, 17.0, 16.5, 17.11]),
];

/// Table V: depth levels with WTA; columns original, then [`METHODS`].
pub const TABLE_V: [(&str, [u32; 6]); 9] = [
    ("tsukuba", [7, 8, 5, 5, 5, 5]),
    ("art", [6, 8, 5, 6, 5, 6]),
    ("books", [7, 6, 5, 7, 5, 7]),
    ("cones", [6, 6, 4, 6, 5, 5]),
    ("laundry", [6, 4, 4, 6, 6, 6]),
    ("moebius", [5, 3, 6, 5, 5, 5]),
    ("reindeer", [6, 5, 7, 5, 5, 5]),
    ("teddy", [7, 7, 4, 6, 5, 5]),
    ("venus", [5, 8, 6, 3, 5, 3]),
];

/// Table VI: depth levels with line growing; columns as [`TABLE_V`].
pub const TABLE_VI: [(&str, [u32; 6]); 9] = [
    ("tsukuba", [7, 7, 7, 7, 7, 4]),
    ("art", [6, 7, 7, 5, 7, 4]),
    ("books", [7, 7, 3, 5, 7, 5]),
    ("cones", [6, 7, 4, 7, 7, 5]),
    ("laundry", [6, 7, 7, 7, 7, 3]),
    ("moebius", [5, 5, 7, 6, 6, 3]),
    ("reindeer", [6, 4, 7, 7, 7, 5]),
    ("teddy", [7, 4, 4, 7, 7, 4]),
    ("venus", [5, 5, 4, 7, 7, 5]),
];

/// Fig. 12: 95 % confidence intervals of the size reduction (%), per [`METHODS`].
pub const REDUCTION_CI: [(f64, f64); 5] = [
    (78.58, 86.01),
    (51.48, 61.54),
    (79.59, 86.22),
    (79.70, 86.22),
    (79.49, 86.00),
];

/// The paper's 95 % confidence interval of the size reduction for a method.
pub fn reduction_ci(method: &str) -> Option<(f64, f64)> {
    METHODS
        .iter()
        .position(|&x| x == method)
        .map(|i| REDUCTION_CI[i])
}

/// The paper's PSNR for a scene and method, if it reported one.
pub fn psnr(scene: &str, method: &str) -> Option<f64> {
    let m = METHODS.iter().position(|&x| x == method)?;
    TABLE_IV
        .iter()
        .find(|(s, _)| *s == scene)
        .map(|(_, v)| v[m])
}

/// The paper's depth-level count for a scene, input ("original" or a method) and table.
pub fn levels(table: &[(&str, [u32; 6])], scene: &str, input: &str) -> Option<u32> {
    let col = if input == "original" {
        0
    } else {
        1 + METHODS.iter().position(|&x| x == input)?
    };
    table.iter().find(|(s, _)| *s == scene).map(|(_, v)| v[col])
}
