# Ember: the two commands are `make render` and `make test` (see README.md).
PY := .venv/bin/python
export PYTHONPATH := $(CURDIR)

.PHONY: setup render render-engine test test-engine test-addon test-other-cpu mutate bench bench-cycles bench-yardstick bench-export zip install-blender clean

setup:
	./scripts/setup.sh

# Main job: the bundled Cornell box, rendered by Ember through the bpy module,
# to out/cornell.png and out/cornell.exr.
render: setup
	$(PY) -P tools/render_blend.py blend_scenes/cornell.blend -o out/cornell

# The engine alone, on its own copy of the Cornell box (no Blender).
render-engine: setup
	$(PY) -m engine --scene cornell --size 512 512 --samples 64 -o out/engine_cornell

# Everything: engine and add-on tests, Cycles comparisons, Blender 3.4 binary
# and bpy 4.2 runs.  Installs what it needs first (apt for Debian's Blender).
# Missing prerequisites fail; EMBER_ALLOW_SKIPS=1 make test skips them (not under CI=true).
# Two pytest-xdist workers (TEST_WORKERS=0: one process): a test file runs
# whole on one worker, the Blender 3.4 binary tests together (tests/conftest.py).
TEST_WORKERS ?= 2
test: setup
	sh tools/setup_test_env.sh
	$(PY) -m pytest tests -q -rfEs -p no:cacheprovider --durations=30 -n $(TEST_WORKERS) --dist loadgroup

test-engine: setup
	$(PY) -m pytest tests/engine -q

# The engine's tests as a CPU without AVX-512 runs them: numba compiles for
# Haswell into a cache of its own and NumPy's AVX-512 loops are switched
# off, so rounding differs from this machine's (docs/testing.md).
test-other-cpu: setup
	NUMBA_CPU_NAME=haswell NUMBA_CACHE_DIR=$${TMPDIR:-/tmp}/ember-numba-haswell \
	NPY_DISABLE_CPU_FEATURES="AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL" \
	$(PY) -m pytest tests/engine -q -p no:cacheprovider

test-addon: setup
	sh tools/setup_test_env.sh
	$(PY) -m pytest tests/addon -q

# The mutation table (docs/testing.md): small errors put into a copy of the
# tree, one at a time, each followed by the tests that must catch it.  Not
# part of make test; about 5-10 minutes.
mutate: setup
	$(PY) tools/mutate.py

bench: setup
	$(PY) -m tools.bench_engine

# Ember against Cycles through Blender on the yardstick scenes (QUICK=1: 64x64).
bench-cycles: setup
	$(PY) -P tools/bench_cycles.py $(if $(QUICK),--quick,)

# Measured time to Cycles' RMSE (Cycles' better light-tree setting, Ember's
# sample count by bisection, 5 seeds each): tools/yardstick.py.
bench-yardstick: setup
	$(PY) -P tools/yardstick.py $(if $(QUICK),--quick,) $(if $(SCENES),--scenes $(SCENES),)

bench-export: setup
	$(PY) -P tools/bench_export.py

zip: setup
	$(PY) tools/build_zip.py

# Build and install into a real Blender: make install-blender BLENDER=/path/to/blender
BLENDER ?= blender
install-blender: setup
	$(PY) tools/install_addon.py --blender $(BLENDER)

clean:
	rm -rf out dist build .pytest_cache
