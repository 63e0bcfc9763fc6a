"""The decoder's analyses (`analysis/decoder_eval.py`) on the tiny model: per rest, blends, example pairs."""
import numpy as np
import pytest


def test_decoder_analyses_on_the_tiny_model(tiny_motion, tiny_corpus, tmp_path):
    from latent_model.analysis import decoder_eval

    transfer, _ = tiny_motion
    c = tiny_corpus
    test = c.split_indices("test")
    m = decoder_eval.evaluate_decoder(transfer, c, test)
    # the characters shared between two processes, their surface features kept on disk (written, then read back):
    # the same metrics
    two = decoder_eval.evaluate_decoder(transfer, c, test, workers=2, surface_cache=tmp_path)
    assert len(list(tmp_path.glob("*.npz"))) == len(test)
    again = decoder_eval.evaluate_decoder(transfer, c, test, surface_cache=tmp_path)
    for other in (two, again):
        assert list(other) == list(m)
        for k, v in m.items():
            assert other[k] == (pytest.approx(v, rel=1e-6, abs=1e-9) if isinstance(v, float) else v), k
    rests = {c.identities[i].rest for i in test}
    assert rests == {"bind", "tpose"}
    for r in rests:
        assert m[f"decoder.rests.{r}.characters"] == 2
        assert np.isfinite(m[f"decoder.rests.{r}.elbowBentLf.mean.explained"])
    # the blend the tiny corpus has; its fractions are of the truth's motion
    key = "decoder.blend.elbowBentLf>kneeBentLf"
    assert m[f"{key}.step_ratio"] >= 1.0 and m[f"{key}.half_a"] > 0 and m[f"{key}.half_b"] > 0
    # example pairs: made on one person, judged on the other
    assert m["decoder.examples.elbow70Lf.kind"] == "amplitude"
    assert np.isfinite(m["decoder.examples.elbow70Lf.explained"])
    md = decoder_eval.markdown(m)
    assert "| tpose | 2 |" in md and "elbowBentLf → kneeBentLf" in md and "elbow70Lf" in md


def test_region_fraction_measures_along_the_truth():
    from latent_model.analysis.decoder_eval import region_fraction

    src = np.zeros((4, 3))
    truth = np.array([[0.02, 0, 0], [0.0, 0.03, 0], [0, 0, 0], [0, 0, 0.001]])
    assert region_fraction(truth, truth, src) == 1.0
    assert region_fraction(src, truth, src) == 0.0
    assert abs(region_fraction(0.5 * truth, truth, src) - 0.5) < 1e-9
    # motion of the wrong direction does not count as the region moving
    assert region_fraction(src + np.array([0, 0, 0.02]), truth, src) == 0.0
