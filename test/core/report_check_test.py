#!/usr/bin/python3
"""The reporting scripts' checks (scripts/write_*.py, targets in scripts/targets.py) on small
fabricated inputs: each script exits 0 when every claim holds (the open targets missed as
docs/RESULTS.md reports them), 1 when a claimed target is missed, 2 when an expected input (a
surface, a split, a preset, a size, a file) is absent. Run by report_check_test (make test);
alone: report_check_test.py SCRIPTS_DIR [unittest arguments].
"""
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

SCRIPTS = None  # set by main
OK, MISSED, MISSING = 0, 1, 2


def run(script, *args):
    p = subprocess.run(["/usr/bin/python3", os.path.join(SCRIPTS, script)] + [str(a) for a in args],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True)
    return p.returncode, p.stdout


def dump(path, obj):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        json.dump(obj, f)
    return path


def timing(ms=1.0):
    st = {"mean_ms": ms, "sd_ms": 0.1, "median_ms": ms, "p95_ms": ms}
    return {"queries": 5, "feature_extraction": dict(st), "bow_transform": dict(st),
            "database_insertion": dict(st), "database_query": dict(st),
            "pose_estimation": dict(st), "end_to_end": dict(st)}


def split(name, day, loc=1.0, mapv=0.9, recall1=1.0, queries=40, verified=100, wrong=0,
          r100p=1.0, errors=None):
    correct = int(round(loc * queries))
    return {"name": name, "day": day, "queries": queries, "queries_with_relevant": queries,
            "queries_without_relevant": 0, "map_at_1000": mapv,
            "recall_at_n": [recall1] * 7, "separation": {"threshold": 0.1, "kept_relevant": 0.5},
            "localization": {"success_rate": correct / float(queries), "correct": correct,
                             "estimated": correct,
                             "position_error_mm": errors if errors is not None else [0.2] * correct,
                             "heading_error_deg": [0.05] * correct},
            "backend": {"verified_poses": verified, "wrong_verified_poses": wrong,
                        "recall_at_100_precision_verified": r100p,
                        "recall_at_100_precision_bow_top1": r100p}}


def preset(name, splits, file=None, row="", e2e_ms=20.0, transform_ms=1.8, query_ms=0.5):
    t = timing()
    t["end_to_end"]["median_ms"] = e2e_ms
    t["bow_transform"]["median_ms"] = transform_ms
    t["database_query"]["median_ms"] = query_ms
    return {"name": name, "file": file or "config/%s.yaml" % name, "table_i_row": row,
            "configuration": "", "database_images": 178, "splits": splits, "timing": t}


class Base(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="gtbow_report_check_")
        self.docs = os.path.join(self.dir, "docs")
        os.makedirs(self.docs)
        with open(os.path.join(self.docs, "RESULTS.md"), "w") as f:
            f.write("# Results\n")

    def tearDown(self):
        shutil.rmtree(self.dir)

    def expect(self, code, script, *args, why=None):
        """Runs script; asserts its exit code and, for a failure, that a MISSED (exit 1) or
        MISSING INPUT (exit 2) line names `why`."""
        got, out = run(script, *args)
        self.assertEqual(got, code, "%s %s: exit %d, wanted %d\n%s" % (script, " ".join(map(str, args)), got, code, out))
        if code != OK:
            tag = "MISSED:" if code == MISSED else "MISSING INPUT:"
            lines = [l for l in out.splitlines() if tag in l]
            self.assertTrue(lines, "no %s line\n%s" % (tag, out))
            if why is not None:
                self.assertTrue(any(why in l for l in lines), "no %s line names %r\n%s" % (tag, why, out))
        return out

    def section(self, name):
        with open(os.path.join(self.docs, "RESULTS.md")) as f:
            text = f.read()
        self.assertIn("<!-- %s:begin -->" % name, text)
        return text


# --- make benchmark (write_results.py)
def eval_results(ha_loc0=1.0, fast_loc180=0.99, days=(0, 30, 90, 180), fast_e2e=20.0):
    def splits(loc_first, loc_last):
        out = []
        for i, d in enumerate(days):
            out.append(split("query_day%03d" % d, d, loc=loc_first if i == 0 else loc_last if i == len(days) - 1 else 1.0))
        for s in out:
            s["separation"]["kept_relevant"] = 0.32  # open target (>= 95%), missed as RESULTS.md says
        return out
    return {"dataset": {"path": "/x/asphalt32k"},
            "presets": [preset("dbow_baseline", splits(0.5, 0.3), row="DBoW"),
                        preset("high_accuracy", splits(ha_loc0, 1.0), row="Ours", e2e_ms=21.4),
                        preset("fast", splits(1.0, fast_loc180), row="Ours Fast", e2e_ms=fast_e2e)]}


class Eval(Base):
    def write(self, res):
        d = os.path.join(self.dir, "eval")
        dump(os.path.join(d, "results.json"), res)
        with open(os.path.join(d, "summary.md"), "w") as f:
            f.write("# Summary\n\ntext\n")
        return d

    def test_all_claims_hold(self):
        d = self.write(eval_results())
        out = self.expect(OK, "write_results.py", "--check", d)
        self.assertIn("Score separation", out)  # the open target, printed as missed
        self.expect(OK, "write_results.py", d, self.docs)
        self.section("eval")

    def test_open_target_fails_with_strict(self):
        self.expect(MISSED, "write_results.py", "--check", "--strict", self.write(eval_results()), why="Score separation")

    def test_claim_missed(self):
        self.expect(MISSED, "write_results.py", "--check", self.write(eval_results(ha_loc0=0.98)), why="Localization success, high accuracy, first day")
        self.expect(MISSED, "write_results.py", "--check", self.write(eval_results(fast_loc180=0.75)), why="fast, oldest day")
        self.expect(MISSED, "write_results.py", "--check", self.write(eval_results(fast_e2e=25.0)), why="rate, fast")

    def test_missed_claim_still_writes_the_section(self):
        self.expect(MISSED, "write_results.py", self.write(eval_results(ha_loc0=0.5)), self.docs)
        self.assertIn("| missed", self.section("eval"))

    def test_day_missing(self):
        self.expect(MISSING, "write_results.py", "--check", self.write(eval_results(days=(0, 30, 180))), why="day 90")

    def test_no_results(self):
        self.expect(MISSING, "write_results.py", "--check", os.path.join(self.dir, "nothing"), why="results.json")


# --- make bench-scaling (write_scaling.py)
def scaling(ha_query=(34.0, 26.0), fast_mem=1.55e9, biggest=1000000, ratio=0.95):
    def sizes(q, mem):
        out = []
        for n in (1000, 32085, biggest):
            out.append({"images": n, "rss_loaded_bytes": mem, "load_cold_ms": 3500, "load_warm_ms": 800,
                        "insert_us": {"median": 170.0 * (ratio if n == biggest else 1.0)},
                        "query_ms": [{"median": q[0]}, {"median": q[1]}]})
        return out
    return {"dataset": "build/benchmark/asphalt32k", "real_images": 32085,
            "presets": [{"name": "high_accuracy", "sizes": sizes(ha_query, 4.55e9)},
                        {"name": "fast", "sizes": sizes((6.3, 4.6), fast_mem)}]}


class Scaling(Base):
    def write(self, data):
        d = os.path.join(self.dir, "bench")
        dump(os.path.join(d, "scaling.json"), data)
        with open(os.path.join(d, "scaling.md"), "w") as f:
            f.write("## Scaling: x\n")
        return d

    def test_all_claims_hold(self):
        d = self.write(scaling())
        self.expect(OK, "write_scaling.py", "--check", d)
        self.expect(OK, "write_scaling.py", d, self.docs)
        self.section("scaling")

    def test_claim_missed(self):
        self.expect(MISSED, "write_scaling.py", "--check", self.write(scaling(ha_query=(34.0, 31.0))), why="median query")
        self.expect(MISSED, "write_scaling.py", "--check", self.write(scaling(fast_mem=4.2e9)), why="fast, 1000000 images: memory")
        self.expect(MISSED, "write_scaling.py", "--check", self.write(scaling(ratio=1.6)), why="insertion")

    def test_size_missing(self):
        self.expect(MISSING, "write_scaling.py", "--check", self.write(scaling(biggest=320000)), why="1000000 images")

    def test_preset_missing(self):
        data = scaling()
        data["presets"].pop()
        self.expect(MISSING, "write_scaling.py", "--check", self.write(data), why="the preset fast")


# --- make bench-map (write_bench_map.py)
def bench_map(identical=100, fast_stall=0.0, ha_stall=26.0, variants=(("fast", True), ("high_accuracy", False))):
    out = []
    for name, keep in variants:
        stall = fast_stall if name == "fast" else ha_stall
        calls = {k: {"during_ms": {"max": 20.0 + stall}, "without_ms": {"max": 20.0}}
                 for k in ("add", "query", "localize")}
        save = {"file_bytes": 6.39e9, "bytes_per_keyframe": 6392.0, "seal_ms": 0.17, "swap_ms": 0.01}
        save.update(calls)
        out.append({"name": name, "keep_descriptors": keep, "keyframes": 1000000,
                    "save": save,
                    "load": {"cold_ms": 2550.0, "warm_ms": 680.0, "rss_after_load_bytes": 1.6e9,
                             "rss_after_queries_bytes": 1.6e9},
                    "loaded": {"localize_ms": {"median": 8.8}},
                    "queries": 100, "identical_answers": identical})
    return {"dataset": "build/benchmark/asphalt32k", "real_keyframes_available": 32085, "variants": out}


class BenchMap(Base):
    def write(self, data):
        d = os.path.join(self.dir, "bench_map")
        dump(os.path.join(d, "bench_map.json"), data)
        with open(os.path.join(d, "bench_map.md"), "w") as f:
            f.write("## Warehouse maps\n")
        return d

    def test_all_claims_hold(self):
        # The high-accuracy preset's stall (26 ms against 10) is an open target: printed, not failed.
        d = self.write(bench_map())
        out = self.expect(OK, "write_bench_map.py", "--check", d)
        self.assertIn("missed, known", out)
        self.expect(OK, "write_bench_map.py", d, self.docs)
        self.section("bench_map")
        self.expect(MISSED, "write_bench_map.py", "--check", "--strict", d, why="high_accuracy")

    def test_answer_changed(self):
        self.expect(MISSED, "write_bench_map.py", "--check", self.write(bench_map(identical=99)), why="99 of 100 identical")

    def test_fast_stall(self):
        # An open target since the December 2026 run (RESULTS.md): printed, failing with --strict.
        self.expect(OK, "write_bench_map.py", "--check", self.write(bench_map(fast_stall=11.0)))
        self.expect(MISSED, "write_bench_map.py", "--check", "--strict", self.write(bench_map(fast_stall=11.0)), why="fast (descriptors kept)")

    def test_variant_missing(self):
        self.expect(MISSING, "write_bench_map.py", "--check", self.write(bench_map(variants=(("fast", True),))), why="high_accuracy, descriptors dropped")


# --- make benchmark-real (write_real_results.py)
PHOTOS = ["ufoai_textures_street001", "ufoai_textures_e8crete03", "ufoai_textures_concrete_g_11",
          "nexuiz_textures_gravel01", "nexuiz_textures_mudground04", "supertuxkart_data_paving_stones_2",
          "lugaru_data_mossrock", "ufoai_textures_concrete_g_9", "nexuiz_textures_ex_cretebase_02",
          "nexuiz_textures_ex_cretebase_03_dark"]
SMOOTH = PHOTOS[7:]
REAL_PRESETS = ["high_accuracy", "fast", "paper_literal", "paper_literal_fast", "authors",
                "ablation/authors/ours_plain_orb", "dbow_baseline", "ablation/features/clahe_only",
                "ablation/features/grid_only", "ablation/features/normalize_grid",
                "ablation/features/adaptive_threshold", "ablation/features/grid_refill",
                "ablation/features/dense_400", "changing_floors", "ablation/changing/no_min_spread",
                "ablation/changing/no_guided",
                "ablation/changing/query_only", "ablation/changing/transient_only",
                "ablation/changing/both_polarities", "ablation/changing/six_inliers",
                "ablation/changing/guided",
                "ablation/changing/guided_repeat_check", "ablation/changing/no_escalate", "ablation/changing/no_backoff",
                "ablation/changing/no_plain_repeat"]
CHANGING_LC = ["changing_floors", "ablation/changing/no_min_spread", "ablation/changing/no_guided",
               "ablation/changing/query_only",
               "ablation/changing/transient_only",
               "ablation/changing/both_polarities", "ablation/changing/guided",
               "ablation/changing/guided_repeat_check", "ablation/changing/no_escalate", "ablation/changing/no_backoff",
                "ablation/changing/no_plain_repeat"]

HELDOUT_PRESETS = ["high_accuracy", "changing_floors", "ablation/changing/no_min_spread",
                   "ablation/changing/no_guided", "ablation/changing/six_inliers",
                   "ablation/changing/guided", "ablation/changing/guided_repeat_check",
                   "ablation/changing/no_escalate", "ablation/changing/no_backoff",
                   "ablation/changing/no_plain_repeat"]


def real_results(photos=PHOTOS, presets=REAL_PRESETS, plain_smooth=0.05, ha_smooth=0.95, ha_map=0.85,
                 drop=None, cf_oldest=0.95, cf_wrong=0):
    out = []
    for name in presets:
        splits = []
        for ph in photos:
            for d in (0, 180):
                if drop == (name, ph, d):
                    continue
                l, m = 1.0, {"dbow_baseline": 0.38}.get(name, 0.7)
                if name == "high_accuracy":
                    m = ha_map
                    l = ha_smooth if ph in SMOOTH and d == 0 else (0.2 if d == 180 else 1.0)
                if name == "paper_literal" and ph in SMOOTH and d == 0:
                    l = plain_smooth
                wrong = 0
                if name == "changing_floors":
                    l = cf_oldest if d == 180 else 1.0
                    wrong = cf_wrong if (ph, d) == (PHOTOS[0], 0) else 0
                splits.append(split("query_day%03d_%s" % (d, ph), d, loc=l, mapv=m, wrong=wrong))
        f = "/x/config/%s.yaml" % name
        out.append(preset(name.split("/")[-1], splits, file=f))
    return {"dataset": {"path": "/x/real"}, "presets": out}


def low_contrast(surface, ha0=0.97, cf180=0.9):
    ps = []
    for name in ["high_accuracy", "fast", "paper_literal", "authors"] + CHANGING_LC:
        l = ha0 if name == "high_accuracy" else 0.5
        l180 = cf180 if name == "changing_floors" else 0.1
        ps.append(preset(name, [split("query_day000", 0, loc=l, queries=30),
                                split("query_day180", 180, loc=l180, queries=30)], file="/x/config/%s.yaml" % name))
    return {"dataset": {"path": "/x/real-%s" % surface}, "presets": ps}


class Real(Base):
    def inputs(self, res=None, smooth_ha0=0.97, surfaces=("smooth_concrete", "epoxy"), cf_smooth=0.9):
        main = dump(os.path.join(self.dir, "real", "results.json"), res or real_results())
        lc = [dump(os.path.join(self.dir, "real-%s" % s, "results.json"),
                   low_contrast(s, smooth_ha0 if s == "smooth_concrete" else 0.0, cf_smooth)) for s in surfaces]
        return [main] + lc

    def test_all_claims_hold(self):
        # Open targets missed as RESULTS.md reports them: day-180 worst 20%, epoxy 0%, fast mAP.
        ins = self.inputs()
        out = self.expect(OK, "write_real_results.py", "--check", *ins)
        self.assertIn("missed, known", out)
        self.expect(OK, "write_real_results.py", ins[0], self.docs, *ins[1:])
        text = self.section("real")
        self.assertIn("plain ORB", text)
        self.assertIn("Floors that change", text)
        # The held-out photographs, when given, get their table.
        held = dump(os.path.join(self.dir, "heldout", "results.json"),
                    real_results(photos=PHOTOS[:2], presets=HELDOUT_PRESETS))
        self.expect(OK, "write_real_results.py", "--heldout", held, ins[0], self.docs, *ins[1:])
        self.assertIn("Held-out photographs", self.section("real"))

    def sequence_inputs(self, cf5_oldest=0.98, wrong=0, renderings=(2, 3, 4), smooth5=0.8,
                        held_wrong=0):
        """The --sequence results of scripts/benchmark_real.sh: rendering 1 with 3 and 5 images,
        renderings 2-4 with 1 and 5, the synthetic surfaces with 3 and 5, the held-out photos."""
        def res(name, n, presets, cf_oldest, surface="photo", photos=PHOTOS, w=0):
            r = real_results(photos=photos, presets=presets, cf_oldest=cf_oldest, cf_wrong=w)
            r["dataset"].update({"name": name, "surface": surface})
            r["protocol"] = {"sequence": n}
            return r

        out = []
        both = ["high_accuracy", "changing_floors"]
        for n in (3, 5):
            out.append(dump(os.path.join(self.dir, "seq1_%d" % n, "results.json"),
                            res("photo_floor_seed1", n, both, cf5_oldest, w=wrong if n == 5 else 0)))
        for r in renderings:
            for n in (1, 5):
                out.append(dump(os.path.join(self.dir, "seq%d_%d" % (r, n), "results.json"),
                                res("photo_floor_seed%d" % r, n, ["changing_floors"],
                                    cf5_oldest if n == 5 else 0.5)))
        for surface in ("smooth_concrete", "epoxy"):
            for n in (3, 5):
                lc = low_contrast(surface)
                lc["dataset"].update({"name": surface + "_synth_seed1", "surface": surface})
                lc["protocol"] = {"sequence": n}
                for p in lc["presets"]:
                    if p["name"] == "changing_floors":
                        p["splits"][1] = split("query_day180", 180, loc=smooth5, queries=30)
                out.append(dump(os.path.join(self.dir, "lc_%s_%d" % (surface, n), "results.json"), lc))
        out.append(dump(os.path.join(self.dir, "held5", "results.json"),
                        res("photo_floor_seed1", 5, both, 0.9, photos=PHOTOS[:2], w=held_wrong)))
        return [a for f in out for a in ("--sequence", f)]

    def maintained_inputs(self, best_oldest=1.0, renderings=(1, 2, 3, 4), placed_wrong=0):
        """The --maintained results of scripts/benchmark_real.sh: every rendering with 1 and 5
        images (rendering 1 single with high_accuracy too), the synthetic surfaces, the held-out
        photos; each preset with its maintenance sessions."""
        def keep(r):
            for p in r["presets"]:
                p["maintenance"] = {
                    "refresh_below_inliers": 60, "min_inliers": 12, "place_fraction": 0.25,
                    "max_views_per_place": 3, "max_theta_sigma": 0.0026,
                    "sessions": [{"split": "session_day%03d" % d, "day": d, "images": 400, "fixes": 398,
                                  "correct": 398, "added": 40, "retired": 10,
                                  "added_wrong": placed_wrong if d == 90 else 0,
                                  "added_error_mm": [0.4, 1.1], "added_error_deg": [0.1, 0.5],
                                  "keyframes_after": 178 + 30 * (1 + d // 90)} for d in (30, 90)]}
            return r

        def res(name, n, presets, cf_oldest, photos=PHOTOS):
            r = real_results(photos=photos, presets=presets, cf_oldest=cf_oldest)
            r["dataset"].update({"name": name, "surface": "photo"})
            r["protocol"] = {"sequence": n}
            return keep(r)

        out = []
        for r in renderings:
            for n in (1, 5):
                presets = ["high_accuracy", "changing_floors"] if (r, n) == (1, 1) else ["changing_floors"]
                out.append(dump(os.path.join(self.dir, "maint%d_%d" % (r, n), "results.json"),
                                res("photo_floor_seed%d" % r, n, presets, best_oldest if n == 5 else 0.9)))
        for surface in ("smooth_concrete", "epoxy"):
            for n in (1, 5):
                lc = low_contrast(surface)
                lc["dataset"].update({"name": surface + "_synth_seed1", "surface": surface})
                lc["protocol"] = {"sequence": n}
                out.append(dump(os.path.join(self.dir, "mlc_%s_%d" % (surface, n), "results.json"), keep(lc)))
        for n in (1, 5):
            out.append(dump(os.path.join(self.dir, "mheld%d" % n, "results.json"),
                            res("photo_floor_seed1", n, ["changing_floors"], 0.9, photos=PHOTOS[:2])))
        return [a for f in out for a in ("--maintained", f)]

    def test_maintained_map_gets_its_table_and_targets(self):
        ins = self.inputs()
        self.expect(OK, "write_real_results.py", *self.sequence_inputs(), *self.maintained_inputs(),
                    ins[0], self.docs, *ins[1:])
        text = self.section("real")
        self.assertIn("A map that keeps up", text)
        self.assertIn("| 4 | `changing_floors` | 5 | maintained |", text)

    def test_maintained_best_configuration_missed(self):
        ins = self.inputs()
        self.expect(MISSED, "write_real_results.py", "--check", *self.sequence_inputs(),
                    *self.maintained_inputs(best_oldest=0.85), *ins,
                    why="the best configuration (changing_floors, a maintained map")

    def test_maintained_view_placed_wrong(self):
        ins = self.inputs()
        self.expect(MISSED, "write_real_results.py", "--check", *self.sequence_inputs(),
                    *self.maintained_inputs(placed_wrong=1), *ins, why="views placed outside")

    def test_maintained_rendering_missing(self):
        ins = self.inputs()
        self.expect(MISSING, "write_real_results.py", "--check", *self.sequence_inputs(),
                    *self.maintained_inputs(renderings=(1, 2, 3)), *ins,
                    why="renderings of the ten photos with a maintained map")

    def test_sequences_get_their_table_and_targets(self):
        ins = self.inputs()
        out = self.expect(OK, "write_real_results.py", *self.sequence_inputs(), ins[0], self.docs, *ins[1:])
        self.assertIn("missed, known", out)  # epoxy, and the worst surface below 90% is open
        text = self.section("real")
        self.assertIn("Sequence queries", text)
        self.assertIn("rendering 4: 1 / 5 images", text)

    def test_sequence_wrong_pose(self):
        ins = self.inputs()
        self.expect(MISSED, "write_real_results.py", "--check", *self.sequence_inputs(wrong=1), *ins,
                    why="changing_floors, sequences, wrong verified poses")

    def test_sequence_wrong_pose_held_out(self):
        ins = self.inputs()
        self.expect(MISSED, "write_real_results.py", "--check", *self.sequence_inputs(held_wrong=1),
                    *ins, why="changing_floors, sequences, wrong verified poses")

    def test_sequence_mean_missed(self):
        ins = self.inputs()
        self.expect(MISSED, "write_real_results.py", "--check", *self.sequence_inputs(cf5_oldest=0.95), *ins,
                    why="5-image sequences on the frozen map, day-180 localization, mean of the surfaces")

    def test_sequence_smooth_concrete_missed(self):
        ins = self.inputs()
        self.expect(MISSED, "write_real_results.py", "--check", *self.sequence_inputs(smooth5=0.7), *ins,
                    why="5-image sequences, synthetic smooth concrete")

    def test_sequence_rendering_missing(self):
        ins = self.inputs()
        self.expect(MISSING, "write_real_results.py", "--check", *self.sequence_inputs(renderings=(2, 3)), *ins,
                    why="4 renderings")

    def test_changing_floors_oldest_day_missed(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(real_results(cf_oldest=0.5)),
                    why="changing_floors, day-180 localization, mean of the surfaces")

    def test_changing_floors_smooth_concrete_missed(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(cf_smooth=0.5),
                    why="changing_floors, synthetic smooth concrete, day-180 localization")

    def test_changing_floors_wrong_pose_on_the_heldout_photos(self):
        held = dump(os.path.join(self.dir, "heldout", "results.json"),
                    real_results(photos=PHOTOS[:2], presets=HELDOUT_PRESETS, cf_wrong=1))
        self.expect(MISSED, "write_real_results.py", "--check", "--heldout", held, *self.inputs(),
                    why="changing_floors, the held-out photographs, single images, wrong verified")

    def test_changing_floors_wrong_pose(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(real_results(cf_wrong=1)),
                    why="changing_floors, wrong verified poses")

    def test_surface_missing(self):
        self.expect(MISSING, "write_real_results.py", "--check", *self.inputs(real_results(photos=PHOTOS[:-1])), why="10 surfaces")

    def test_split_missing(self):
        res = real_results(drop=("ablation/features/grid_only", "nexuiz_textures_gravel01", 180))
        self.expect(MISSING, "write_real_results.py", "--check", *self.inputs(res), why="grid_only: the split query_day180_nexuiz_textures_gravel01")

    def test_preset_missing(self):
        res = real_results(presets=[p for p in REAL_PRESETS if p != "paper_literal"])
        self.expect(MISSING, "write_real_results.py", "--check", *self.inputs(res), why="the preset paper_literal")

    def test_low_contrast_surface_missing(self):
        self.expect(MISSING, "write_real_results.py", "--check", *self.inputs(surfaces=("smooth_concrete",)), why="epoxy")

    def test_no_splits_at_all(self):
        # The old script printed "all claims hold" when no split matched.
        res = real_results()
        for p in res["presets"]:
            for s in p["splits"]:
                s["name"] = "query_" + s["name"]
        self.expect(MISSING, "write_real_results.py", "--check", *self.inputs(res), why="surfaces (the run has 0)")

    def test_plain_orb_contrast_flipped(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(real_results(plain_smooth=0.5)), why="plain ORB")

    def test_ours_fails_on_smooth_concrete(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(real_results(ha_smooth=0.6)), why="high accuracy, day-0 localization, each smooth concrete")

    def test_map_below_twice_dbow(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(real_results(ha_map=0.7)), why="high_accuracy, day 0: mAP")

    def test_low_contrast_smooth_concrete_missed(self):
        self.expect(MISSED, "write_real_results.py", "--check", *self.inputs(smooth_ha0=0.9), why="smooth_concrete: low-contrast")


def real_small(ha=(1.0, 1.0), plain=(1.0, 0.3), photos=("ufoai_textures_street001", "ufoai_textures_concrete_g_9")):
    ps = []
    for name, locs in (("high_accuracy", ha), ("paper_literal", plain)):
        ps.append(preset(name, [split("query_day000_%s" % ph, 0, loc=l, queries=20) for ph, l in zip(photos, locs)],
                         file="/x/config/%s.yaml" % name))
    return {"dataset": {"path": "/x/real"}, "presets": ps}


class RealSmall(Base):
    def path(self, res):
        return dump(os.path.join(self.dir, "small", "results.json"), res)

    def test_all_claims_hold(self):
        self.expect(OK, "write_real_results.py", "--check", "--small", self.path(real_small()))

    def test_plain_orb_localizes_smooth_concrete(self):
        self.expect(MISSED, "write_real_results.py", "--check", "--small", self.path(real_small(plain=(1.0, 0.6))), why="plain ORB")

    def test_high_accuracy_below_ninety(self):
        self.expect(MISSED, "write_real_results.py", "--check", "--small", self.path(real_small(ha=(1.0, 0.85))), why="concrete_g_9: high accuracy")

    def test_surface_missing(self):
        self.expect(MISSING, "write_real_results.py", "--check", "--small",
                    self.path(real_small(ha=(1.0,), plain=(1.0,))), why="concrete_g_9")


# --- make benchmark-verification (write_verification_results.py)
VER_PRESETS = ["ha_words", "ha_words_spread", "ha_words_fraction", "ha_words_angle", "ha_words_second",
               "ha_words_checks", "ha_descriptors", "ha_descriptors_sigma", "ha_descriptors_consensus",
               "high_accuracy", "ha_no_descriptors", "fast_words", "fast_descriptors", "fast",
               "fast_no_descriptors", "paper_literal"]


def verification(real=True, wrong=None, r100p=1.0, r100p_first=None, presets=VER_PRESETS):
    wrong = wrong or {}
    ps = []
    for name in presets:
        ss = []
        if real:
            for ph in PHOTOS:
                for d in (0, 180):
                    ss.append(split("query_day%03d_%s" % (d, ph), d, verified=150,
                                    wrong=wrong.get(name, 0) if ph == PHOTOS[0] and d == 0 else 0,
                                    r100p=(r100p_first if r100p_first is not None and ph == PHOTOS[0] else r100p)
                                    if name == "high_accuracy" else 1.0))
        else:
            ss = [split("query_day000", 0, verified=500, wrong=wrong.get(name, 0)), split("query_day180", 180, verified=500)]
        ps.append(preset(name, ss, file="/x/config/ablation/verification/%s.yaml" % name))
    return {"dataset": {"path": "/x"}, "presets": ps}


class Verification(Base):
    def inputs(self, real=None, s4k=None):
        r = dump(os.path.join(self.dir, "v", "real.json"), real or verification())
        s = dump(os.path.join(self.dir, "v", "s4k.json"), s4k or verification(real=False))
        return ["real=" + r, "s4k=" + s]

    def test_all_claims_hold(self):
        # One photo at 0.9 (the mossy stone's repeated patches), the day-0 splits at 0.99.
        ins = self.inputs(real=verification(wrong={"ha_words": 30, "paper_literal": 33}, r100p_first=0.9))
        self.expect(OK, "write_verification_results.py", "--check", *ins)
        self.expect(OK, "write_verification_results.py", self.docs, *ins)
        self.section("verification")
        self.assertIn("ha_no_descriptors", self.section("descriptors"))

    def test_wrong_pose_of_a_preset(self):
        self.expect(MISSED, "write_verification_results.py", "--check", *self.inputs(real=verification(wrong={"fast": 1})), why="real, fast: wrong")
        self.expect(MISSED, "write_verification_results.py", "--check",
                    *self.inputs(s4k=verification(real=False, wrong={"fast_no_descriptors": 1})), why="s4k, fast_no_descriptors")

    def test_r100p(self):
        self.expect(MISSED, "write_verification_results.py", "--check", *self.inputs(real=verification(r100p=0.9)), why="R@100P")

    def test_preset_missing(self):
        real = verification(presets=[p for p in VER_PRESETS if p != "fast_no_descriptors"])
        self.expect(MISSING, "write_verification_results.py", "--check", *self.inputs(real=real), why="fast_no_descriptors")

    def test_dataset_missing(self):
        self.expect(MISSING, "write_verification_results.py", "--check", self.inputs()[0], why="s4k")


# --- make benchmark-keypoints (write_keypoint_results.py)
def keypoint_run(d, shift_m=0.0, lose_query=False, drop_split=False):
    ps, rows = [], []
    for name in ("high_accuracy", "fast", "paper_literal"):
        ss = []
        for ph in PHOTOS:
            for day in (0, 180):
                sname = "query_day%03d_%s" % (day, ph)
                if drop_split and name == "fast" and ph == PHOTOS[3] and day == 180:
                    continue
                loc = 0.975 if lose_query and name == "high_accuracy" and ph == PHOTOS[0] and day == 0 else 1.0
                ss.append(split(sname, day, loc=loc, verified=2))
                for rank in (1, 2):
                    x = 0.1 + (shift_m if name == "fast" and rank == 1 and ph == PHOTOS[1] else 0.0)
                    rows.append({"preset": name, "split": sname, "query": sname + "_000000.png", "rank": rank,
                                 "image": "database_%06d.png" % rank, "x": "%.6f" % x, "y": "0.200000",
                                 "theta": "1.000000", "wrong": "0", "error_mm": "0.2"})
        ps.append(preset(name, ss))
    dump(os.path.join(d, "results.json"), {"dataset": {"path": "/x/real"}, "presets": ps})
    with open(os.path.join(d, "verifications.csv"), "w") as f:
        w = csv.DictWriter(f, fieldnames=["preset", "split", "query", "rank", "image", "x", "y", "theta", "wrong",
                                          "error_mm"])
        w.writeheader()
        w.writerows(rows)
    return d


class Keypoints(Base):
    def runs(self, **exact):
        return (keypoint_run(os.path.join(self.dir, "stored")), keypoint_run(os.path.join(self.dir, "exact"), **exact))

    def test_all_claims_hold(self):
        s, e = self.runs(shift_m=0.00004)
        self.expect(OK, "write_keypoint_results.py", "--check", s, e)
        self.expect(OK, "write_keypoint_results.py", self.docs, s, e)
        self.assertIn("0.0400 mm", self.section("keypoints"))

    def test_pose_moved(self):
        self.expect(MISSED, "write_keypoint_results.py", "--check", *self.runs(shift_m=0.0002), why="largest move")

    def test_localization_changed(self):
        self.expect(MISSED, "write_keypoint_results.py", "--check", *self.runs(lose_query=True), why="queries localized")

    def test_split_missing(self):
        self.expect(MISSING, "write_keypoint_results.py", "--check", *self.runs(drop_split=True), why="fast: 20 query splits")


# --- make benchmark-authors (write_authors_results.py)
AUTHOR_PRESETS = ["paper_literal.yaml", "ablation/authors/exact_search.yaml", "ablation/authors/converged.yaml",
                  "ablation/authors/per_bin.yaml", "ablation/authors/hamming_sigma580.yaml",
                  "ablation/authors/hamming.yaml", "ablation/authors/all_authors_exact.yaml", "authors.yaml",
                  "ablation/authors/ours_plain_orb.yaml", "high_accuracy.yaml", "paper_literal_fast.yaml",
                  "authors_fast.yaml", "ablation/authors/fast_plain_orb.yaml", "fast.yaml", "dbow_baseline.yaml"]
CONF = ("features:\n  contrast: clahe\n  grid_cols: 4\n  grid_rows: 3\nvocabulary:\n  kind: akm\n  metric: hamming\n"
        "  ann: ivf\n  nprobe: 48\n  checks: 0\n  kmeans_stop_fraction: 0.001\n  kmeans_iterations: 30\n"
        "bow:\n  sigma: 24.083\n  soft_assignment: 3\n  normalization: global\n")


def authors(ha180=0.90, fast_query=0.18, presets=AUTHOR_PRESETS):
    ps = []
    for rel in presets:
        m180 = ha180 if rel == "high_accuracy.yaml" else 0.65
        q = fast_query if rel == "fast.yaml" else 0.5
        p = preset(os.path.basename(rel)[:-5], [split("query_day000", 0, mapv=0.95), split("query_day180", 180, mapv=m180)],
                   file="/x/config/" + rel, query_ms=q)
        p["configuration"] = CONF
        ps.append(p)
    return {"dataset": {"path": "/x/s4k"}, "presets": ps}


class Authors(Base):
    def path(self, res):
        return dump(os.path.join(self.dir, "authors", "results.json"), res)

    def test_all_claims_hold(self):
        self.expect(OK, "write_authors_results.py", "--check", self.path(authors()))
        self.expect(OK, "write_authors_results.py", self.path(authors()), self.docs)
        self.section("authors")

    def test_claim_missed(self):
        self.expect(MISSED, "write_authors_results.py", "--check", self.path(authors(ha180=0.82)), why="high_accuracy: mAP day 180")
        self.expect(MISSED, "write_authors_results.py", "--check", self.path(authors(fast_query=0.4)), why="fast: database query")

    def test_preset_missing(self):
        self.expect(MISSING, "write_authors_results.py", "--check",
                    self.path(authors(presets=AUTHOR_PRESETS[:-1])), why="dbow_baseline.yaml")


# --- make soak (write_soak.py)
def soak(failures=0, growth=207.7):
    return {"seconds": 601, "warmup_s": 60, "samples": [[0, 100, 0], [601, 300, 100]],
            "images_received": 1, "images_processed": 1, "images_dropped": 0, "images_rejected": 0,
            "keyframes": 10, "map_mb": 1.0, "rss_warm_mb": 111, "rss_end_mb": 318, "rss_peak_mb": 321,
            "rss_growth_mb": growth, "map_growth_mb": 179.1, "allowed_growth_mb": 422.2,
            "services": [{"name": "localize", "calls": 10, "failures": failures, "median_ms": 1,
                          "p99_ms": 2, "max_ms": 3}]}


class Soak(Base):
    def path(self, data):
        d = os.path.join(self.dir, "soak")
        dump(os.path.join(d, "soak.json"), data)
        return d

    def test_all_claims_hold(self):
        self.expect(OK, "write_soak.py", "--check", self.path(soak()))

    def test_claim_missed(self):
        self.expect(MISSED, "write_soak.py", "--check", self.path(soak(failures=1)), why="service calls failed")
        self.expect(MISSED, "write_soak.py", "--check", self.path(soak(growth=500.0)), why="memory growth")

    def test_figure_missing(self):
        data = soak()
        del data["allowed_growth_mb"]
        self.expect(MISSING, "write_soak.py", "--check", self.path(data), why="allowed_growth_mb")


# --- make benchmark-kernels (write_kernels.py)
KERNEL_NAMES = ("portable", "popcnt", "avx2", "avx512")


def kernels_run(out, transform=None, train_avx2="14.1", lacks=(), answers_differ=None,
                cpu="AMD EPYC 7763 64-Core Processor"):
    """A benchmark_kernels.sh output directory: the timing eval, the trainings and the dumps."""
    transform = dict({"portable": 13.8, "popcnt": 4.6, "avx2": 2.6, "avx512": 1.8}, **(transform or {}))
    presets = []
    for name in ("high_accuracy", "fast", "high_accuracy_bound", "high_accuracy_nprobe16"):
        by = []
        for k in KERNEL_NAMES:
            ran = "avx2" if k in lacks else k
            stats = {st: {"median_ms": 1.0} for st in ("feature_extraction", "database_query",
                                                      "pose_estimation", "end_to_end")}
            # Fewer lists: a faster transform (the table's ratio columns are checked).
            stats["bow_transform"] = {"median_ms": transform[ran] * (0.5 if "nprobe" in name else 1.0)}
            by.append(dict(stats, requested=k, hamming=ran, l2_bytes=ran))
        splits = [{"name": "query_day%03d_floor" % d, "day": d, "map_at_1000": 0.8 - d / 1000,
                   "localization": {"success_rate": 0.99 - d / 1000},
                   "backend": {"wrong_verified_poses": 0}} for d in (0, 180)]
        presets.append({"name": name, "database_images": 178, "splits": splits,
                        "configuration": "vocabulary:\n  train_nprobe: 0\n  nprobe: %d\n" % (
                            16 if "nprobe" in name else 48),
                        "timing": {"queries": 200, "by_kernel": by}})
    dump(os.path.join(out, "eval_timing", "results.json"),
         {"dataset": {"image_width": 320, "image_height": 240}, "presets": presets})
    with open(os.path.join(out, "cpu.txt"), "w") as f:
        f.write(cpu + "\n")
    for k in KERNEL_NAMES + ("avx2_no_bound",):
        with open(os.path.join(out, "train_%s.txt" % k), "w") as f:
            f.write("  akm, ..., in %s s\n" % (train_avx2 if k == "avx2" else "20.0"))
    for k in KERNEL_NAMES:
        dump(os.path.join(out, "eval_%s" % k, "results.json"), {})
        with open(os.path.join(out, "rankings_%s.high_accuracy.csv" % k), "w") as f:
            f.write("query,rank,image,score\n0,0,%d,0.5\n" % (7 if k == answers_differ else 3))


class Kernels(Base):
    def run_dir(self, **kw):
        d = os.path.join(self.dir, "kernels")
        kernels_run(d, **kw)
        return d

    def test_all_claims_hold(self):
        d = self.run_dir()
        self.expect(OK, "write_kernels.py", "--check", d)
        self.expect(OK, "write_kernels.py", d, self.docs)
        self.assertIn("| avx2 | high_accuracy |", self.section("kernels"))
        # The search's effort: the presets probing fewer lists, with their accuracy.
        self.assertIn("| high_accuracy_nprobe16 | 16 | 0.800 / 0.620 | 99.0% / 81.0% | 0 | "
                      "0.90 / 1.30 / 2.30 / 6.90 | x1.44 | x2.56 | x7.67 |", self.section("kernels"))
        self.assertNotIn("| avx2 | high_accuracy_nprobe16 |", self.section("kernels"))

    def test_open_targets_missed_fail_only_with_strict(self):
        d = self.run_dir(transform={"avx2": 2.8, "popcnt": 4.8})
        self.expect(OK, "write_kernels.py", "--check", d)
        self.expect(MISSED, "write_kernels.py", "--check", "--strict", d, why="avx2 against avx512")

    def test_the_authors_timing_is_compared_on_its_cpu_only(self):
        # 3.1 ms with avx2 misses the target (8.7 / 3) on the CPU the authors' code was timed on
        # (an open target: it fails with --strict)...
        self.expect(OK, "write_kernels.py", "--check", self.run_dir(transform={"avx2": 3.1}))
        self.expect(MISSED, "write_kernels.py", "--check", "--strict",
                    self.run_dir(transform={"avx2": 3.1}), why="authors")
        # ...and on another CPU the row has no verdict.
        d = self.run_dir(transform={"avx2": 3.1}, cpu="Intel(R) Xeon(R) Processor")
        self.expect(OK, "write_kernels.py", d, self.docs)
        self.assertIn("not checked: the authors' code was timed on an AMD EPYC", self.section("kernels"))
        # The family and model that benchmark_kernels.sh adds change nothing: any EPYC is checked.
        self.expect(OK, "write_kernels.py", "--check",
                    self.run_dir(transform={"avx2": 4.6}, cpu="AMD EPYC (family 23, model 1)"))
        self.expect(MISSED, "write_kernels.py", "--check", "--strict",
                    self.run_dir(transform={"avx2": 4.6}, cpu="AMD EPYC (family 23, model 1)"),
                    why="authors")

    def test_training_too_slow(self):
        self.expect(MISSED, "write_kernels.py", "--check", self.run_dir(train_avx2="31.5"), why="training")

    def test_answers_of_a_kernel_differ(self):
        self.expect(MISSED, "write_kernels.py", "--check", self.run_dir(answers_differ="popcnt"),
                    why="equal the portable")

    def test_a_kernel_the_cpu_lacks_is_left_out(self):
        d = self.run_dir(lacks=("avx512",))
        self.expect(OK, "write_kernels.py", d, self.docs)
        self.assertNotIn("| avx512 |", self.section("kernels"))
        # The search's ratios are then against avx2, the widest kernel that ran.
        self.assertIn("| 1.30 / 2.30 / 6.90 | x1.77 | x5.31 |", self.section("kernels"))

    def test_answers_missing(self):
        d = self.run_dir()
        shutil.rmtree(os.path.join(d, "eval_avx2"))
        self.expect(MISSING, "write_kernels.py", "--check", d, why="GTBOW_SIMD=avx2")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    SCRIPTS = sys.argv[1]
    unittest.main(argv=[sys.argv[0]] + sys.argv[2:], verbosity=2)
