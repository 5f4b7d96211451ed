"""Fuzzing the job and embodiment YAML readers (`pipeline.config`): valid files are generated, then broken as
text (a value swapped for one out of range, of the wrong type, huge, deeply nested, an alias bomb or a
dangling alias; a key repeated) or as bytes (cut, NUL, not UTF-8). Every example ends in a job (whose
hash is computed) or a one-line ConfigError naming the file, within 30 s and 256 MB."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis import strategies as st

from pipeline.config import ConfigError, load_embodiment, load_job
from tests.fuzz.bounds import within
from tests.fuzz.breaking import broken_bytes
from tests.fuzz.outcome import result_or_one_line_error

SECONDS, MEGABYTES = 30, 256
NAMES = st.from_regex(r"[A-Za-z0-9_-]{1,10}", fullmatch=True)
FINITE = {"allow_nan": False, "allow_infinity": False}

SENSORS = st.fixed_dictionaries({}, optional={
    "width": st.integers(8, 1024), "height": st.integers(8, 1024), "hfov": st.floats(1, 179, **FINITE),
    "model": st.sampled_from(["ideal", "structured_light"]), "near": st.floats(0.01, 0.5, **FINITE)})
LIGHTS = st.one_of(
    st.just({"kind": "ambient"}),
    st.fixed_dictionaries({"kind": st.just("spot"), "power": st.floats(1, 500, **FINITE)}, optional={
        "material": st.sampled_from(["diffuse", "principled"]), "cone": st.floats(1, 180, **FINITE),
        "indirect": st.fixed_dictionaries({}, optional={"bounces": st.integers(0, 16)})}))
EMBODIMENTS = st.fixed_dictionaries({
    "name": NAMES, "sensor": SENSORS, "illumination": LIGHTS,
    "placements": st.lists(st.sampled_from([0.1, 0.5, 1.0, 1.2]), min_size=1, max_size=3, unique=True)},
    optional={"body": st.fixed_dictionaries({"radius": st.floats(0.05, 0.5, **FINITE), "height": st.just(1.5)})})
JOBS = st.fixed_dictionaries({
    "name": NAMES,
    "scenes": st.fixed_dictionaries({"procedural": st.fixed_dictionaries({}, optional={
        "count": st.integers(1, 5), "seed": st.integers(0, 2**40), "detail": st.floats(0.05, 1, **FINITE)})}),
    "embodiments": st.lists(EMBODIMENTS, min_size=1, max_size=3, unique_by=lambda e: e["name"])},
    optional={
        "seed": st.integers(0, 2**62),
        "plan": st.fixed_dictionaries({}, optional={"trajectories_per_scene": st.integers(1, 50),
                                                     "min_frames": st.integers(2, 100), "max_frames": st.integers(100, 600),
                                                     "max_step": st.floats(0.01, 0.2, **FINITE)}),
        "render": st.fixed_dictionaries({}, optional={"frames_per_shard": st.integers(1, 256)}),
        "evaluate": st.fixed_dictionaries({}, optional={"ks": st.lists(st.integers(1, 15), min_size=1, max_size=4)}),
        "split": st.fixed_dictionaries({}, optional={"empty_threshold": st.floats(0.1, 1, **FINITE)}),
        "runtime": st.fixed_dictionaries({}, optional={"max_retries": st.integers(0, 5)}),
    })


def _alias_bomb(levels: int) -> str:
    """A flow list whose anchors nest ten aliases per level: 10^levels leaves if it were expanded."""
    items = ["&l0 [x, x, x, x, x, x, x, x, x, x]"]
    items += [f"&l{i} [{', '.join([f'*l{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "[" + ", ".join(items) + "]"


BAD_VALUES = st.one_of(
    st.sampled_from(["100000000000", "-1", "0", ".inf", "-.inf", ".nan", "1.0e+400", "0x7fffffffffffffffffff",
                     "2024-13-45", "~", "[]", "{}", "yes", '"\\0"', '"a\\0b"', "!!binary AAAA", "!!binary ?!",
                     "!!python/object/apply:os.system [echo]", "*nowhere", "&x [*x]", "{<<: *nowhere}", "'", "[1, 2"]),
    st.integers(300, 6000).map(lambda digits: "9" * digits),  # Python refuses int() of more than 4,300 digits
    st.integers(-2**70, 2**70).map(str),
    st.floats().map(lambda value: repr(value).replace("inf", ".inf").replace("nan", ".nan")),
    st.integers(2, 3000).map(lambda n: "[" * n + "]" * n),
    st.integers(2, 3000).map(lambda n: "{a: " * n + "1" + "}" * n),
    st.integers(2, 9).map(_alias_bomb),
    st.text(max_size=20).map(lambda text: yaml.safe_dump(text).removesuffix("\n...\n").strip()),
)


@st.composite
def broken_yaml(draw: st.DrawFn, documents: st.SearchStrategy[dict]) -> bytes:
    """A valid document dumped as block YAML, then broken as YAML text or as bytes."""
    lines = yaml.safe_dump(draw(documents), sort_keys=False).splitlines()
    how = draw(st.sampled_from(("value", "value", "repeat_key", "alias", "bytes")))
    at = draw(st.integers(0, len(lines) - 1))
    key, colon, _ = lines[at].partition(": ")
    if how == "value" and colon:
        lines[at] = f"{key}: {draw(BAD_VALUES)}"
    elif how == "repeat_key":
        lines.insert(at, lines[at])
    elif how == "alias":  # a later value refers to an earlier one: legal YAML, maybe of the wrong type there
        scalars = [i for i, line in enumerate(lines) if ": " in line and not line.rstrip().endswith(":")]
        if len(scalars) >= 2:
            first, later = sorted(draw(st.lists(st.sampled_from(scalars), min_size=2, max_size=2, unique=True)))
            lines[first] = lines[first].replace(": ", ": &v ", 1)
            lines[later] = lines[later].partition(": ")[0] + ": *v"
    text = ("\n".join(lines) + "\n").encode()
    return draw(broken_bytes(text)) if how == "bytes" else text


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz-config")


def _job_and_hash(path: Path) -> str:
    return load_job(path).hash()  # the hash walks the whole validated job (json.dumps)


@given(data=broken_yaml(JOBS))
def test_a_broken_job_file_is_a_job_or_one_line(folder, data):
    path = folder / "job.yaml"
    path.write_bytes(data)
    result_or_one_line_error(lambda: within(lambda: _job_and_hash(path), SECONDS, MEGABYTES), ConfigError, str(path))


@given(data=broken_yaml(EMBODIMENTS), through_job=st.booleans())
def test_a_broken_embodiment_file_is_an_embodiment_or_one_line(folder, data, through_job):
    path = folder / "robot.yaml"
    path.write_bytes(data)
    job = folder / "uses-robot.yaml"
    job.write_text("name: t\nscenes: {procedural: {count: 1}}\nembodiments: [robot.yaml]\n")
    read = (lambda: _job_and_hash(job)) if through_job else (lambda: load_embodiment(path).model_dump_json())
    result_or_one_line_error(lambda: within(read, SECONDS, MEGABYTES), ConfigError, (str(path), str(job)))


@given(job=JOBS)
def test_every_generated_job_is_valid(folder, job):
    """The generator makes valid jobs, so the broken ones are broken by the breaking alone."""
    path = folder / "valid.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    assert load_job(path).name == job["name"]
