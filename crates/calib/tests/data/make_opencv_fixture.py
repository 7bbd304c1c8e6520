"""Writes opencv_stereo.yml with cv2.FileStorage, the fixture the calib crate
reads to prove it loads files OpenCV wrote. Run once from the repository root:

    python3 crates/calib/tests/data/make_opencv_fixture.py

A rig with exact inputs (the test checks them), rectified by cv2.stereoRectify;
D1 as 1x5 doubles, D2 as 5x1 float32, keys out of our order, comments.
"""
import cv2
import numpy as np

M1 = np.array([[670.5, 0, 322.0], [0, 668.0, 238.25], [0, 0, 1]])
M2 = np.array([[668.0, 0, 318.5], [0, 667.5, 241.0], [0, 0, 1]])
D1 = np.array([[-0.3, 0.12, 0.001, -0.0015, -0.02]])
D2 = np.array([[-0.28], [0.1], [0.0005], [-0.001], [-0.01]], dtype=np.float32)
R = cv2.Rodrigues(np.array([0.004, -0.012, 0.002]))[0]
T = np.array([[-0.06], [0.0005], [0.001]])
size = (640, 480)
R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(M1, D1.astype(np.float64), M2, D2.astype(np.float64),
                                            size, R, T, alpha=0)

fs = cv2.FileStorage("crates/calib/tests/data/opencv_stereo.yml", cv2.FILE_STORAGE_WRITE)
fs.writeComment("written by cv2 %s (make_opencv_fixture.py)" % cv2.__version__)
for key, value in [("R", R), ("T", T), ("image_height", 480), ("image_width", 640),
                   ("M1", M1), ("D1", D1), ("M2", M2), ("D2", D2)]:
    fs.write(key, value)
fs.writeComment("stereoRectify, alpha 0")
for key, value in [("R1", R1), ("R2", R2), ("P1", P1), ("P2", P2), ("Q", Q)]:
    fs.write(key, value)
fs.release()
