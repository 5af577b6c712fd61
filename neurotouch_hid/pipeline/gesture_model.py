"""Constants of the learned gesture type (``learned.py``): written by
``benchmarks/train_gesture_classifier.py --write`` (scikit-learn LogisticRegression, C = 1, on 29890
windows of the tuning users 5 and 8, seed 1, of the families default, powerlaw, indent, camera,
drift, fingers, strong, markers, noise, flicker). Features: scale_share, rotation_share,
translation_share, signed_scale_share, signed_rotation_share, contact_radial, contact_tangential,
contact_count, log_intensity_px; classes: push, pinch, zoom, twist_cw, twist_ccw."""

import numpy as np

MEAN = np.array(
    [0.43272982, 0.32243539, 0.24483479, -0.05134445, -0.00575155, -0.04076358, -0.03135638, 2.16239545, 2.10518055]
)
SCALE = np.array(
    [0.41036645, 0.39374309, 0.34231006, 0.59415442, 0.50888616, 0.66060719, 0.61008319, 0.72993931, 0.73168368]
)
WEIGHTS = np.array(
    [
        [
            -0.24917105,
            -0.54536881,
            0.92602204,
            -0.87547444,
            0.93298588,
            0.70780393,
            0.13815993,
            -0.11631425,
            0.80924655,
        ],
        [
            1.85369499,
            -1.4673694,
            -0.53439177,
            -1.11510341,
            -0.6921269,
            -1.33037287,
            -0.00752832,
            0.08954942,
            -0.82254132,
        ],
        [
            1.73236454,
            -1.76879786,
            -0.04222006,
            1.91868639,
            -0.38776472,
            1.28265604,
            0.04017844,
            0.00976561,
            -0.61046379,
        ],
        [
            -1.23671919,
            1.43943836,
            -0.17312043,
            -0.35822271,
            -1.26985694,
            0.34811061,
            -1.22026002,
            0.63827995,
            0.12210936,
        ],
        [-2.10016929, 2.34209771, -0.17628978, 0.43011416, 1.41676268, -1.00819771, 1.04944997, -0.62128073, 0.5016492],
    ]
)
INTERCEPT = np.array([1.69201919, -0.44449102, -0.51020223, 0.45754728, -1.19487322])
