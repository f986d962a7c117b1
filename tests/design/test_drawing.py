from matplotlib.image import imread

from groundstation.design.drawing import draw_level
from groundstation.design.enumeration import enumerate_levels


def test_draw_level_writes_a_legible_png(tmp_path):
    *_, lv = enumerate_levels(5)
    out = draw_level(lv.topologies(), tmp_path / "n5.png", "n=5")
    img = imread(out)
    assert img.shape[0] > 400 and img.shape[1] > 600
    # Blue connection patches are present: some pixels close to the connection colour (0.12, 0.37, 0.75).
    rgb = img[..., :3]
    blue = (abs(rgb[..., 0] - 0.12) < 0.05) & (abs(rgb[..., 1] - 0.37) < 0.05) & (abs(rgb[..., 2] - 0.75) < 0.05)
    assert blue.sum() > 24 * 4 * 20
