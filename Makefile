# One-command set-up and the project's main jobs. Everything runs inside $(VENV),
# created and installed on first use (torch pinned by constraints.txt).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip install --quiet -c constraints.txt
STAMP := $(VENV)/.installed
# torch's CPU build: PyPI's Linux x86_64 torch is the CUDA one (several GB). torch is installed
# first, alone, with this index added; --retries 0 so that where it cannot be reached (machines
# that keep the wheel on disk, which pip's own configuration points at) pip goes on at once.
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu

.PHONY: test test-runtime lint format demo clean-venv

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) --upgrade pip
	$(PIP) --retries 0 --extra-index-url $(TORCH_INDEX) torch
	$(PIP) -e '.[dev]'
	touch $(STAMP)

## test: create the virtual environment if needed, lint, run the whole test suite (in a
## random order: pytest-randomly prints the seed, `-p randomly --randomly-seed N` repeats it)
test: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(PY) -m pytest

## test-runtime: the service, client and runtime tests in $(RUNTIME_VENV), an environment with
## the serve and client extras and the test tools only: it checks that torch is not there
RUNTIME_VENV ?= .venv-runtime
RUNTIME_STAMP := $(RUNTIME_VENV)/.installed
$(RUNTIME_STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(RUNTIME_VENV)
	$(RUNTIME_VENV)/bin/python -m pip install --quiet -c constraints.txt --upgrade pip
	$(RUNTIME_VENV)/bin/python -m pip install --quiet -c constraints.txt -e '.[test-runtime]'
	touch $(RUNTIME_STAMP)

test-runtime: $(RUNTIME_STAMP)
	$(RUNTIME_VENV)/bin/python -c "import importlib.util as u, sys; \
		sys.exit('torch is installed in $(RUNTIME_VENV)' if u.find_spec('torch') else 0)"
	$(RUNTIME_VENV)/bin/python -m pytest --runtime-only

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

format: $(STAMP)
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

## demo: generate a small dataset and write its preview montage
demo: $(STAMP)
	$(VENV)/bin/sdc-data generate --out data/demo --models 6 --views 2 --seed 0
	$(VENV)/bin/sdc-data preview data/demo --count 6

clean-venv:
	rm -rf $(VENV) $(RUNTIME_VENV)

## serve: start the inference service on the shipped model (http://127.0.0.1:8000/docs);
## flags through SERVE_ARGS, e.g. make serve SERVE_ARGS="--port 9000 --threads 2"
.PHONY: serve
SERVE_ARGS ?=
serve: $(STAMP)
	$(VENV)/bin/sdc-serve $(SERVE_ARGS)

## docker-check: build the CPU image with podman and run it for real: serve a generated frame,
## compare with onnxruntime on the host, healthcheck, non-root, no torch; skips (exit 0, says
## why) without root or ../shared/container. DOCKER_CHECK_ARGS="--model PATH" for another model
.PHONY: docker-check
DOCKER_CHECK_ARGS ?=
docker-check: $(STAMP)
	bash docker/check.sh $(DOCKER_CHECK_ARGS)

## model: regenerate the dataset, train, evaluate and export the shipped model with its card
## (about 4 h on 2 idle cores; PRESET=paper on a GPU). The shipped weights come from five runs,
## each starting from the one before: the first design (sdcnet-v1, cpu preset), its FSNet 16
## more epochs; then the plane-fit depth path trained on that FSNet (stage 2), and FSNet with
## the refiner 8 + 8 more epochs with a soft-IOU term on a quarter, then half, of the training
## frames. The first model is kept in runs/first/ for the side-by-side reports. `make ablation` after it refreshes the card's ablation tables
.PHONY: model
PRESET ?= cpu
RUN ?= runs/sdcnet
FIRST ?= runs/first/sdcnet.pt
model: $(STAMP)
	$(VENV)/bin/sdc-data generate --out data/paper --models 126 --views 64 --size 1024 --seed 0
	$(VENV)/bin/sdc-train fit --data data/paper --out $(RUN) --preset $(PRESET) --variant sdcnet-v1
	$(VENV)/bin/sdc-train fit --data data/paper --out $(RUN)-ft --preset $(PRESET) \
		--init-weights $(RUN)/best.pt --fsnet-epochs 16 --epochs 0 --lr 5e-4 --seed 1
	mkdir -p $(dir $(FIRST))
	$(VENV)/bin/sdc-train ship --checkpoint $(RUN)-ft/best_stage1.pt --out $(FIRST)
	$(VENV)/bin/sdc-export --checkpoint $(FIRST) --out $(FIRST:.pt=.onnx)
	$(VENV)/bin/sdc-train fit --data data/paper --out runs/v2 --preset $(PRESET) --variant sdcnet \
		--init-segmentation $(FIRST)
	$(VENV)/bin/sdc-train fit --data data/paper --out runs/v2-ft --preset $(PRESET) \
		--init-weights runs/v2/best.pt --fsnet-epochs 8 --epochs 0 --lr 5e-4 --seed 1 --iou-loss 1 \
		--train-samples 1584
	$(VENV)/bin/sdc-train fit --data data/paper --out runs/v2-ft2 --preset $(PRESET) \
		--init-weights runs/v2-ft/best_stage1.pt --fsnet-epochs 8 --epochs 0 --lr 2.5e-4 --seed 2 \
		--iou-loss 1 --train-samples 3168
	$(VENV)/bin/sdc-train ship --checkpoint runs/v2-ft2/best_stage1.pt --out models/sdcnet.pt
	$(MAKE) reports

## reports: evaluate the shipped checkpoint beside the first model and the classical fill (test
## split and real meshes), export it with its parity check, refresh the gallery and the card
.PHONY: reports
reports: $(STAMP)
	$(VENV)/bin/sdc-train ship --checkpoint models/sdcnet.pt --out runs/ablation/plane-alone.pt \
		--zero fdcnet.head
	$(VENV)/bin/sdc-train ship --checkpoint models/sdcnet.pt --out runs/ablation/no-refiner.pt \
		--zero refiner.correction
	$(VENV)/bin/sdc-train evaluate --checkpoint models/sdcnet.pt runs/ablation/plane-alone.pt $(FIRST) \
		--names sdcnet "its plane fit alone" "first model" \
		--data data/paper --split test --floor --limit 288 --out models/eval_test.json \
		--title "Synthetic test split (18 unseen models, every fourth frame)"
	$(VENV)/bin/sdc-export --checkpoint models/sdcnet.pt --out models/sdcnet.onnx \
		--metrics models/eval_test.json
	$(VENV)/bin/sdc-train evaluate --onnx models/sdcnet.onnx --data data/paper --split test --limit 288 \
		--out models/eval_test_onnx.json \
		--title "Synthetic test split through onnxruntime (the service's numbers, every fourth frame)"
	$(VENV)/bin/sdc-train evaluate --segmentation-only --data data/paper --split test --limit 288 \
		--checkpoint models/sdcnet.pt runs/ablation/no-refiner.pt runs/v2/best.pt \
		--names sdcnet "its refiner off" "before the FSNet fine-tunes" --out models/eval_mask_ablation.json \
		--title "Mask ablation, test split (every fourth frame): the refiner and the FSNet fine-tunes"
	$(VENV)/bin/sdc-train real --checkpoint models/sdcnet.pt $(FIRST) --names sdcnet "first model" \
		--onnx models/sdcnet.onnx --floor --out docs/real
	$(MAKE) card

## bench: regenerate the benchmark tables and plots in docs/benchmarks/ (needs data/paper;
## FP16/INT8 variants are made in runs/variants, they are not shipped)
.PHONY: bench
bench: $(STAMP)
	$(VENV)/bin/sdc-export --checkpoint models/sdcnet.pt --out runs/variants/sdcnet.onnx \
		--variants fp16 int8 --calibration-data data/paper
	$(PY) -m benchmarks.pipeline_latency --onnx models/sdcnet.onnx $(FIRST:.pt=.onnx)
	$(PY) -m benchmarks.model_latency --checkpoint models/sdcnet.pt --onnx runs/variants/sdcnet.onnx
	$(PY) -m benchmarks.accuracy_speed --checkpoint models/sdcnet.pt --onnx runs/variants/sdcnet.onnx \
		--data data/paper --split test --limit 192
	$(PY) -m benchmarks.service_latency --requests 60
	$(PY) -m benchmarks.load --requests 2000 --concurrency 32

## ablation: the paper's Tables 4 and 5 with the cpu recipe (each Table 5 run took ~21 min on 2 cores; needs
## $(RUN) from `make model`). Table 5: every fusion variant trains stage 2 on $(RUN)'s frozen
## 8-epoch FSNet (the baseline has none), evaluated beside $(RUN)'s own SDCNet. Table 4: FSNet
## on gray or sparse alone, stage 1 only, against $(RUN)'s stage 1 on both.
.PHONY: ablation
FUSIONS := fsnet fsnet+cca fsnet+sa
ablation: $(STAMP)
	for v in $(FUSIONS); do $(VENV)/bin/sdc-train fit --data data/paper --out runs/ablation-$$v \
		--preset $(PRESET) --variant $$v --init-segmentation $(RUN)/best_stage1.pt || exit 1; done
	$(VENV)/bin/sdc-train fit --data data/paper --out runs/ablation-baseline --preset $(PRESET) \
		--variant baseline
	for i in gray sparse; do $(VENV)/bin/sdc-train fit --data data/paper --out runs/ablation-fsnet-$$i \
		--preset $(PRESET) --fsnet-inputs $$i --epochs 0 || exit 1; done
	$(VENV)/bin/sdc-train evaluate --data data/paper --split test --limit 288 --out models/eval_ablation.json \
		--checkpoint runs/ablation-baseline/best.pt $(foreach v,$(FUSIONS),runs/ablation-$(v)/best.pt) $(RUN)/best.pt \
		--names "(a) baseline: guided conv., no FSNet" "(b) + FSNet" "(c) + FSNet + CCA" "(d) + FSNet + SA" "(e) + FSNet + CCA + SA = SDCNet" \
		--title "Table 5 ablation, test split: each component added to the GuideNet-style baseline (cpu recipe, one seed; every fourth test frame)"
	$(VENV)/bin/sdc-train evaluate --data data/paper --split test --segmentation-only \
		--out models/eval_fsnet_inputs.json \
		--checkpoint runs/ablation-fsnet-gray/best_stage1.pt runs/ablation-fsnet-sparse/best_stage1.pt $(RUN)/best_stage1.pt \
		--names "FSNet on gray" "FSNet on sparse depth" "FSNet on both" \
		--title "Table 4 ablation, test split: FSNet's inputs (8 epochs of stage 1 each, mask metrics only)"
	$(MAKE) card

## card: rewrite models/MODEL_CARD.md from the checkpoint and the evaluation reports
.PHONY: card
card: $(STAMP)
	$(VENV)/bin/sdc-train card --checkpoint models/sdcnet.pt --onnx models/sdcnet.onnx \
		--report models/eval_test.json models/eval_test_onnx.json models/eval_mask_ablation.json \
		models/eval_ablation.json \
		$(wildcard models/eval_fsnet_inputs.json) \
		docs/real/real_spacecraft.json --notes models/NOTES.md --out models/MODEL_CARD.md
