# Ember: the two commands are `make render` and `make test` (see README.md).
PY := .venv/bin/python
export PYTHONPATH := $(CURDIR)

.PHONY: setup render test test-engine bench clean

setup:
	./scripts/setup.sh

render: setup
	$(PY) -P tools/render_blend.py blend_scenes/cornell_box.blend -o out/cornell_box

render-engine: setup
	$(PY) -m engine --scene cornell --size 512 512 --samples 64 -o out/engine_cornell

test:
	EMBER_WITH_BLENDER=1 ./scripts/setup.sh
	$(PY) -m pytest tests -q -rfE --durations=15

test-engine: setup
	$(PY) -m pytest tests/engine -q

bench: setup
	$(PY) -m tools.bench_engine

clean:
	rm -rf out .pytest_cache
