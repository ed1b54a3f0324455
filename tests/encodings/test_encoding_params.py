"""Typed encoding parameters and the plug-in declarations: every registered encoding's ``Params`` round-trips, bad
settings are refused with messages that say where (directly, through ``from_mapping`` and through a recipe file),
stores are read leniently, registration is loud, capabilities are declared, and the hallucination curve is fitted
by ``finalize`` over every probe."""

import importlib
import json
import pickle
from math import pi, sqrt

import numpy as np
import pytest

from bakery.encodings import ENCODINGS, Encoding, EncodingParams, FieldSpec, NoParams, register
from bakery.encodings.sh import SH2
from bakery.encodings.splitsum import SplitSum
from bakery.encodings.zh3 import ZH3Hallucinated
from bakery.errors import ConfigError
from bakery.irradiance.zh3 import PAPER_HALLUCINATION_CURVE, fit_hallucination_curve
from bakery.pipeline.recipe import load_recipe
from bakery.probe import ProbeBatch
from bakery.sphere.cubemap import cube_texel_directions
from bakery.sphere.fibonacci import fibonacci_directions

WHERE = "scene.toml: encoding_settings"
MODULES = ("sh", "zh3", "zh3_hallucinated_solved", "quantized", "splitsum", "shexp", "hybrid")


# ------------------------------------------------------------------------------------------------ round trips
@pytest.mark.parametrize("name", list(ENCODINGS))
def test_defaults_round_trip(name):
    cls = ENCODINGS[name]
    defaults = cls.Params()
    as_dict = defaults.as_dict()
    assert json.loads(json.dumps(as_dict)) == as_dict
    assert cls.Params.from_mapping(as_dict, where=f"{WHERE}.{name}") == defaults
    assert cls.Params.from_stored(json.loads(json.dumps(as_dict))) == defaults
    # a store's settings (Params + derived settings) read back to the instance's Params
    encoding = cls()
    assert cls.Params.from_stored(json.loads(encoding.settings_json())) == encoding.params
    assert cls.from_settings(json.loads(encoding.settings_json())).settings_json() == encoding.settings_json()
    assert cls(**encoding.settings).params == encoding.params  # derived keys are accepted and ignored
    assert defaults.replace() == defaults


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_params_are_frozen_dataclasses_declared_on_the_class(name):
    cls = ENCODINGS[name]
    assert "Params" in cls.__dict__ and issubclass(cls.Params, EncodingParams)
    with pytest.raises(AttributeError):
        cls.Params().some_field = 1


def test_accepted_conversions():
    shexp = ENCODINGS["shexp"].Params.from_mapping({"alpha_max": 1, "alpha_min": 0.3}, where="w")
    assert shexp.alpha_max == 1.0 and isinstance(shexp.alpha_max, float)
    curve = ZH3Hallucinated.Params.from_mapping({"curve": [0.5, 1]}, where="w")
    assert curve.curve == (0.5, 1.0) and curve.as_dict() == {"curve": [0.5, 1.0]}
    assert SplitSum.Params.from_mapping({"face_size": None}, where="w").face_size is None
    assert SplitSum.Params.from_mapping({"face_size": 32}, where="w").face_size == 32
    # numpy scalars count as their Python types (per-probe overrides may come from arrays)
    assert ENCODINGS["shexp"].Params(alpha_min=np.float32(0.25)).alpha_min == 0.25
    # the coarsest fit grid follows a finer finest grid (as before: min(min_fit_face_size, fit_face_size))
    assert ENCODINGS["shexp"].Params(fit_face_size=4).min_fit_face_size == 4


# ------------------------------------------------------------------------------------------------ bad settings
BAD = [
    ("shexp", {"p_band": "four"}, "p_band"),
    ("shexp", {"p_band": 4.0}, "p_band"),
    ("zh3_quantized", {"sqrt_companding": "no"}, "sqrt_companding"),
    ("sh3_quantized", {"sqrt_companding": 0}, "sqrt_companding"),
    ("shexp", {"alpha_minn": 0.3}, "alpha_minn"),
    ("splitsum", {"n_levels": -3}, "n_levels"),
    ("splitsum", {"face_size": 0}, "face_size"),
    ("shexp", {"alpha_min": 0.8, "alpha_max": 0.5}, "alpha_min"),
    ("shexp", {"alpha_min": -0.1}, "alpha_min"),
    ("shexp", {"n_normals": 2, "n_views": 2, "n_alphas": 2}, "n_alphas"),  # 8 design rows < 33 coefficients
    ("shexp_lights", {"alpha_max": 1.5}, "alpha_max"),
    ("shexp_lights", {"max_lights": True}, "max_lights"),
    ("splitsum", {"min_face_size": False}, "min_face_size"),
    ("shexp", {"alpha_max": True}, "alpha_max"),
    ("shexp", {"fit": "magic"}, "fit"),
    ("shexp", {"fit": "dense"}, "fit"),  # legacy stored value: read from stores, not accepted in recipes
    ("shexp_lights", {"light_radius_deg": 95.0}, "light_radius_deg"),
    ("shexp_lights", {"light_threshold": 0.0}, "light_threshold"),
    ("zh3_hallucinated", {"curve": "magic"}, "curve"),
    ("zh3_hallucinated", {"curve": [0.6]}, "curve"),
    ("zh3_hallucinated", {"curve": ["a", "b"]}, "curve"),
    ("zh3_hallucinated", {"fit_samples": 3}, "fit_samples"),  # set by finalize, not a recipe key
    ("sh2", {"anything": 1}, "anything"),
]


@pytest.mark.parametrize("name,values,key", BAD, ids=[f"{n}-{k}" for n, _, k in BAD])
def test_bad_settings_are_refused_naming_where_encoding_and_key(name, values, key):
    where = f"{WHERE}.{name}"
    with pytest.raises(ConfigError) as error:
        ENCODINGS[name].Params.from_mapping(values, where=where)
    message = str(error.value)
    assert message.startswith(where + ": ") and name in message and key in message, message
    assert isinstance(error.value, ValueError) and error.value.key == key
    assert error.value.exit_code == 3


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_params_encodings_and_errors_pickle(name):
    """Workers receive encodings and may raise parameter errors across process borders."""
    cls = ENCODINGS[name]
    encoding = cls()
    again = pickle.loads(pickle.dumps(encoding))
    assert again.params == encoding.params and again.settings_json() == encoding.settings_json()
    with pytest.raises(ConfigError) as error:
        cls.Params.from_mapping({"no_such_key": 1}, where="w")
    copy = pickle.loads(pickle.dumps(error.value))
    assert type(copy) is type(error.value) and str(copy) == str(error.value) and copy.key == "no_such_key"


def test_unknown_key_lists_the_known_ones():
    with pytest.raises(ConfigError) as error:
        ENCODINGS["shexp"].Params.from_mapping({"alpha_minn": 0.3}, where="r.toml: encoding_settings.shexp")
    assert str(error.value).startswith("r.toml: encoding_settings.shexp: unknown key 'alpha_minn'; known: p_band, ")
    assert "alpha_min, alpha_max" in str(error.value)


def test_wrong_type_names_expected_type_and_value():
    with pytest.raises(ConfigError, match=r"w: p_band must be int, got 'four' \(str\)"):
        ENCODINGS["shexp"].Params.from_mapping({"p_band": "four"}, where="w")
    with pytest.raises(ConfigError, match=r"w: n_levels must be >= 1, got -3"):
        SplitSum.Params.from_mapping({"n_levels": -3}, where="w")


def test_direct_construction_and_replace_validate():
    with pytest.raises(ConfigError, match="n_levels"):
        SplitSum.Params(n_levels=-3)
    with pytest.raises(ConfigError, match="n_levels"):
        SplitSum.Params().replace(n_levels=0)
    with pytest.raises(ConfigError, match="unknown key 'levels'"):
        SplitSum.Params().replace(levels=3)
    with pytest.raises(ValueError, match="splitsum: n_levels"):
        SplitSum(n_levels=-3)
    with pytest.raises(ValueError, match="shexp: unknown key 'alpha_minn'"):
        ENCODINGS["shexp"](alpha_minn=0.3)
    with pytest.raises(TypeError):
        ENCODINGS["shexp_lights"](ENCODINGS["shexp"].Params())


def _toml_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


@pytest.mark.parametrize("name,values,key", BAD, ids=[f"{n}-{k}" for n, _, k in BAD])
def test_recipe_with_bad_encoding_settings_names_file_encoding_and_key(tmp_path, name, values, key):
    path = tmp_path / "bad_settings.toml"
    body = "\n".join(f"{k} = {_toml_value(v)}" for k, v in values.items())
    path.write_text(f'name = "bad"\n[targets]\nirradiance = ["sh2"]\n[encoding_settings.{name}]\n{body}\n')
    with pytest.raises(ConfigError) as error:
        load_recipe(str(path))
    message = str(error.value)
    assert str(path) in message and f"encoding_settings.{name}" in message and key in message, message
    assert error.value.exit_code == 3


def test_recipe_with_good_encoding_settings_loads(tmp_path):
    path = tmp_path / "good.toml"
    path.write_text('name = "good"\n[targets]\nirradiance = ["zh3_hallucinated"]\nreflection = ["shexp", "splitsum"]\n'
                    '[encoding_settings.shexp]\nalpha_min = 0.3\nalpha_max = 1\nfit = "log"\n'
                    '[encoding_settings.splitsum]\nface_size = 32\nn_levels = 4\n'
                    '[encoding_settings.zh3_hallucinated]\ncurve = "fit"\n')
    recipe = load_recipe(str(path))
    assert recipe.encoding_settings["shexp"]["alpha_min"] == 0.3
    assert recipe.encoding_settings["zh3_hallucinated"] == {"curve": "fit"}


# ------------------------------------------------------------------------------------------------ stored settings
def test_from_stored_is_lenient_and_maps_legacy_values():
    shexp = ENCODINGS["shexp"].Params.from_stored({"fit": "dense", "p_band": 3, "unrelated": [1, 2]})
    assert shexp.fit == "log" and shexp.p_band == 3
    assert ENCODINGS["shexp"].Params.from_stored({"fit": "fast"}).fit == "log"
    split = SplitSum.from_settings({"face_size": 128, "n_levels": 6, "min_face_size": 32,
                                    "level_alphas": [0.0, 0.04, 0.16, 0.36, 0.64, 1.0],
                                    "roughness_to_level": "level = sqrt(alpha) * (n_levels - 1)"})
    assert split.params == SplitSum.Params(face_size=128)
    old = ZH3Hallucinated.from_settings({"curve": [0.55, 0.1], "fit_samples": 30, "fitted": True})
    assert old.params.curve == (0.55, 0.1) and old.curve() == (0.55, 0.1)
    assert json.loads(old.settings_json()) == {"curve": [0.55, 0.1], "fit_samples": 30, "fitted": True}


def test_splitsum_without_face_size_defaults_to_64():
    assert SplitSum.Params().face_size is None
    assert SplitSum().params.face_size == 64 and SplitSum().chain.face_size == 64
    assert SplitSum(SplitSum.Params().replace(face_size=16)).chain.face_size == 16


# ------------------------------------------------------------------------------------------------ capabilities
CAPABILITIES = {
    # name: (max_band, radiance_sh_field, accepts_alpha_range, follows_bake_face_size)
    "sh2": (1, "radiance_sh", False, False),
    "sh3": (2, "radiance_sh", False, False),
    "zh3": (2, "radiance_sh", False, False),
    "zh3_solved": (2, "radiance_sh", False, False),
    "zh3_deringed": (2, "radiance_sh", False, False),
    "zh3_hallucinated": (1, "radiance_sh", False, False),
    "zh3_hallucinated_solved": (1, "radiance_sh", False, False),
    "zh3_quantized": (2, None, False, False),
    "sh3_quantized": (2, None, False, False),
    "splitsum": (None, None, False, True),
    "shexp": (None, None, True, False),
    "shexp_lights": (None, None, True, False),
    "shexp_hybrid": (None, None, True, True),
}


@pytest.mark.parametrize("name", list(CAPABILITIES))
def test_capabilities(name):
    cls = ENCODINGS[name]
    assert (cls.max_band, cls.radiance_sh_field, cls.accepts_alpha_range, cls.follows_bake_face_size) == \
        CAPABILITIES[name]
    flags = {"zh3_hallucinated": "hallucination_hurts", "zh3_hallucinated_solved": "solved_hallucination_hurts"}
    assert cls.worse_than == ((flags[name], SH2) if name in flags else None)
    if cls.radiance_sh_field is not None:
        spec = {s.name: s for s in cls().field_specs()}[cls.radiance_sh_field]
        assert spec.dtype == "float32" and spec.shape in ((4, 3), (9, 3))
        assert spec.shape[0] == (cls.max_band + 1) ** 2 or name.startswith("zh3")
    if cls.accepts_alpha_range:
        params = cls.Params().replace(alpha_min=0.3, alpha_max=0.6)
        assert cls(params).model.alpha_min == 0.3


def test_every_registered_encoding_has_declared_capabilities():
    assert set(ENCODINGS) == set(CAPABILITIES)


@pytest.mark.parametrize("module", MODULES)
def test_module_docstrings_declare_defines_parameters_references(module):
    mod = importlib.import_module(f"bakery.encodings.{module}")
    doc = mod.__doc__
    assert "Defines" in doc and "Parameters" in doc and "References" in doc
    defined = [cls for cls in ENCODINGS.values() if cls.__module__ == mod.__name__]
    assert defined
    for cls in defined:
        assert cls.__name__ in doc and cls.name in doc


# ------------------------------------------------------------------------------------------------ registry
def _toy(name="test_toy", kind="reflection", params=NoParams):
    namespace = {"name": name, "kind": kind, "description": "test only",
                 "field_specs": lambda self: (FieldSpec("x", (1,), "float32", "x"),),
                 "encode": lambda self, batch: {"x": np.zeros((batch.count, 1), np.float32)}}
    if params is not None:
        namespace["Params"] = params
    return type("Toy", (Encoding,), namespace)


@pytest.mark.parametrize("make,match", [
    (lambda: _toy(name="sh2"), "registered twice"),
    (lambda: _toy(kind="glossy"), "unknown kind"),
    (lambda: _toy(params=None), "Params"),
    (lambda: _toy(params=dict), "Params"),
    (lambda: _toy(kind="irradiance"), "max_band"),
])
def test_registration_is_loud(make, match):
    before = dict(ENCODINGS)
    with pytest.raises(ValueError, match=match):
        register(make())
    assert ENCODINGS == before


def test_registration_is_all_or_nothing():
    before = dict(ENCODINGS)
    with pytest.raises(ValueError, match="unknown kind"):
        register(_toy(name="test_ok"), _toy(name="test_bad", kind="nope"))
    assert ENCODINGS == before


# ------------------------------------------------------------------------------------------------ finalize
def _varied_batch(count=8, face=8):
    d = cube_texel_directions(face)
    rng = np.random.default_rng(5)
    cubes = []
    for _ in range(count):
        sun = rng.normal(size=3)
        sun /= np.linalg.norm(sun)
        sharp = rng.uniform(4.0, 40.0)
        colour = rng.uniform(0.5, 5.0, size=3)
        sky = rng.uniform(0.05, 0.5, size=3) * (0.6 + 0.4 * d[..., 1:2])
        cubes.append(np.exp(sharp * (d @ sun - 1.0))[..., None] * colour + sky)
    return ProbeBatch(np.stack(cubes).astype(np.float32))


def _listing_1(sh, curve, n):
    """[ZH3] Listing 1 transcribed literally for one probe (radiance SH sh[k] RGB) with curve (c2, c1)."""
    lum = np.array([0.2126, 0.7152, 0.0722])
    axis = np.array([-sh[3] @ lum, -sh[1] @ lum, sh[2] @ lum])
    axis /= np.linalg.norm(axis)
    ratio = np.abs(np.stack([-sh[3], -sh[1], sh[2]], 0).T @ axis) / sh[0]
    zonal = sh[0] * (curve[1] * ratio + curve[0] * ratio * ratio)
    fz = n @ axis
    zh_dir = sqrt(5 / (16 * pi)) * (3 * fz * fz - 1)
    c1 = sqrt(3 / (4 * pi))
    linear = pi * sh[0] / (2 * sqrt(pi)) + (2 * pi / 3) * c1 * (
        np.outer(-n[:, 1], sh[1]) + np.outer(n[:, 2], sh[2]) + np.outer(-n[:, 0], sh[3]))
    return linear + pi * 0.25 * np.outer(zh_dir, zonal)


def test_hallucination_curve_is_fitted_by_finalize_over_every_probe():
    batch = _varied_batch()
    encoding = ZH3Hallucinated(curve="fit")
    assert [s.name for s in encoding.aux_specs()] == ["radiance_sh3"]
    assert ZH3Hallucinated().aux_specs() == ()
    encoded = encoding.encode(batch)
    assert encoded["radiance_sh3"].shape == (batch.count, 9, 3) and encoded["radiance_sh3"].dtype == np.float32
    fields = {s.name: encoded[s.name] for s in encoding.field_specs()}
    aux = {s.name: encoded[s.name] for s in encoding.aux_specs()}
    normals = fibonacci_directions(40)
    with pytest.raises(ValueError, match="finalize"):
        encoding.evaluate_irradiance(fields, normals)

    params = encoding.finalize(fields, aux)
    expected, used, fitted = fit_hallucination_curve(aux["radiance_sh3"].astype(np.float64))
    assert fitted and used == 3 * batch.count and params.curve == expected and params.curve != PAPER_HALLUCINATION_CURVE
    assert (params.fit_samples, params.fitted) == (used, True)
    # the float32 aux array gives the curve of the full-precision projection
    np.testing.assert_allclose(params.curve, fit_hallucination_curve(batch.radiance_sh(2))[0], rtol=1e-3)
    stored = json.loads(ZH3Hallucinated(params).settings_json())
    assert stored == {"curve": list(expected), "fit_samples": used, "fitted": True}

    finalized = ZH3Hallucinated.from_settings(stored)
    assert finalized.aux_specs() == () and finalized.finalize(fields, {}) == finalized.params
    values = finalized.evaluate_irradiance(fields, normals)
    for j in range(batch.count):
        sh = fields["radiance_sh"][j].astype(np.float64)
        np.testing.assert_allclose(values[j], _listing_1(sh, expected, normals), rtol=1e-10, atol=1e-12)


def test_hallucination_finalize_falls_back_to_the_paper_curve_with_few_probes():
    batch = _varied_batch(count=2)
    encoding = ZH3Hallucinated(curve="fit")
    encoded = encoding.encode(batch)
    params = encoding.finalize({"radiance_sh": encoded["radiance_sh"]}, {"radiance_sh3": encoded["radiance_sh3"]})
    assert params.curve == PAPER_HALLUCINATION_CURVE and params.fitted is False and params.fit_samples == 6
    with pytest.raises(ValueError, match="radiance_sh3"):
        encoding.finalize({"radiance_sh": encoded["radiance_sh"]}, {})


@pytest.mark.parametrize("name", [n for n in ENCODINGS if n != "zh3_hallucinated"])
def test_finalize_defaults_to_the_params(name):
    encoding = ENCODINGS[name]()
    assert encoding.aux_specs() == () and encoding.finalize({}, {}) is encoding.params


def test_importing_the_encodings_backs_the_operator_cache_with_files():
    from bakery import operator_cache
    from bakery.reflection.tables import OperatorCache

    assert OperatorCache.load is operator_cache.load and OperatorCache.save is operator_cache.save
