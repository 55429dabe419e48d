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

## model: regenerate the data, train, evaluate and export the shipped model with its card (the
## third model's steps about 2 h of training on 2 idle cores and 1 h of data, the fourth's 38 min
## and 8 min; PRESET=paper on a GPU). The third design
## (scale-free inputs, a fixed working-pixel budget, pre-fills that follow the returns' spacing,
## an uncertainty head) is trained on the `mixed` world, warm-started from the second shipped
## model (git $(PREVIOUS), whose card tells its own five runs on the paper's world), in the three
## steps the third model took: FSNet one epoch; FSNet three more and stage 2 three (its
## run had a six-epoch schedule and was stopped after three; its best epoch was the first); FSNet
## fine-tuned three more epochs on the trained FDCNet; its sigma calibrated on val, the scale
## head alone, then with the depth-edge term. The fourth model widens that FSNet
## (--fsnet-growth 2) and trains it 25 epochs in three runs on views 0-11 of the same world,
## the depth networks kept; then its sigma is calibrated again the same way. The fifth model
## fine-tunes that FSNet 14 more epochs in two runs on 99 models none of the others
## saw (data/mixed-s1, seed 1), its depth networks and sigma the fourth's. The sixth
## adds FSNet's coarse context branch (--fsnet-context) and trains FSNet 12 epochs on 99 new
## models again (data/mixed-s2, seed 2; 13 min), its depth networks and sigma the fifth's. The
## seventh trains that FSNet 10 more epochs on 99 new models (data/mixed-s4, seed 4;
## 16 min), half of its training crops grown to hold the whole spacecraft
## (--whole-target-share 0.5), its depth networks and sigma the sixth's. The eighth
## (shipped) trains that FSNet 8 more epochs on one GPU (an H200 with 16 cores; 3 min), on
## the frames 16 cores rendered of 800 new models in 150 s (data/mixed-s5, seed 5: 1576 of the
## 4116 train and val frames; on another machine the set rendered in that time differs), its
## depth networks and sigma the seventh's. The ninth is the mean of the eighth's
## weights and two fine-tunes of its FSNet on one GPU, side by side on the frames 16 cores
## rendered of 800 new models in 220 s (data/mixed-s7, seed 7: 2144 frames), at lr 3e-4 and
## 1e-4, each stopped by its 270 s slot after 8 of its 10 epochs (`sdc-train average`). The
## tenth is the mean of the ninth and one fine-tune of its FSNet on 2 cores (8
## epochs at lr 3e-4, 18 min) on 2058 frames of 686 new models (data/mixed-s10, seed 10;
## 10 min to render), its depth networks and sigma the seventh's. The eleventh is the tenth's
## recipe once more, on 2058 new frames drawn in both render styles (data/mixed-s62, seed 62,
## --styles ours pbr; 59 min to render beside other work), averaged with the tenth. The twelfth
## to the fourteenth repeat it with frames of the weakest worlds drawn apart beside the earlier
## rounds' (the comments below); the fifteenth is the mean of the fourteenth, counted
## twice, and two fine-tunes of it: on new frames of the flash, docking, wide-multibeam and
## `any` worlds (seed 67), and on those with the earth and sun-moon worlds' beside them. The
## sixteenth (shipped) is the same mean once more: the fifteenth counted twice and two
## fine-tunes of it on the second of those sets at lr 1e-4 (seeds 68 and 69).
.PHONY: model
PRESET ?= cpu
PREVIOUS ?= e6a386e
RUN ?= runs/v3
FIT := $(VENV)/bin/sdc-train fit --data data/mixed --preset $(PRESET) --iou-loss 1 --workers 2 \
	--val-samples 40
# the fourth model: FSNet twice as wide (--fsnet-growth 2), trained on views 0-11 of the same
# world's models (the same frames as data/mixed's, fewer of them), its depth networks kept
FIT12 := $(VENV)/bin/sdc-train fit --data data/mixed-v12 --preset $(PRESET) --iou-loss 1 \
	--workers 2 --fsnet-growth 2 --epochs 0
# the fifth model: that FSNet fine-tuned on new models of the same world
FITS1 := $(VENV)/bin/sdc-train fit --data data/mixed-s1 --preset $(PRESET) --iou-loss 1 \
	--iou-over tile --fsnet-growth 2 --epochs 0
# the sixth model: that FSNet with its coarse context branch, trained on new models again
FITS2 := $(VENV)/bin/sdc-train fit --data data/mixed-s2 --preset $(PRESET) --iou-loss 1 \
	--iou-over tile --fsnet-growth 2 --fsnet-context --epochs 0
# the seventh model: that FSNet on new models again, half its crops holding the whole target
FITS4 := $(VENV)/bin/sdc-train fit --data data/mixed-s4 --preset $(PRESET) --iou-loss 1 \
	--iou-over tile --fsnet-growth 2 --fsnet-context --epochs 0 --whole-target-share 0.5
# the eighth model: that FSNet on many more new models, on a GPU (GPU_WORKERS cores)
GPU_WORKERS ?= 16
FITS5 := $(VENV)/bin/sdc-train fit --data data/mixed-s5 --preset $(PRESET) --iou-loss 1 \
	--iou-over tile --fsnet-growth 2 --fsnet-context --epochs 0 --whole-target-share 0.5 \
	--batch-size 16 --samples-per-epoch 3000 --val-samples 150 --workers 10
# the ninth: two fine-tunes of the eighth side by side on one GPU, averaged with it
FITS7 := $(VENV)/bin/sdc-train fit --data data/mixed-s7 --preset $(PRESET) --iou-loss 1 \
	--iou-over tile --fsnet-growth 2 --fsnet-context --epochs 0 --whole-target-share 0.5 \
	--batch-size 16 --samples-per-epoch 4000 --val-samples 150 --workers 7 \
	--init-weights runs/eighth/shipped.pt --fsnet-epochs 10
# the 2-core fine-tune of FSNet from the tenth model on: 8 epochs of 4000 crops, half of them
# holding the whole target; each model's own data and starting weights below
FSNET_FINETUNE := $(VENV)/bin/sdc-train fit --preset $(PRESET) --iou-loss 1 --iou-over tile \
	--fsnet-growth 2 --fsnet-context --epochs 0 --whole-target-share 0.5 --batch-size 16 \
	--samples-per-epoch 4000 --val-samples 150 --workers 1 --fsnet-epochs 8
# the tenth: the ninth's recipe on 2 cores (one fine-tune of the ninth, averaged with it)
FITS10 := $(FSNET_FINETUNE) --data data/mixed-s10 --init-weights runs/ninth/shipped.pt
# the eleventh: the same recipe on frames in both render styles, from the tenth
FITS62 := $(FSNET_FINETUNE) --data data/mixed-s62 --init-weights runs/tenth/shipped.pt
# the twelfth: the same from the eleventh on mixed frames beside frames of the flash and docking
# worlds alone (`sdc-data merge`)
FITS64 := $(FSNET_FINETUNE) --data data/hard-s64 --init-weights runs/eleventh/shipped.pt
# the thirteenth: the same from the twelfth, with frames of the wide-multibeam, any and sun-moon
# worlds alone beside the twelfth's
FITS65 := $(FSNET_FINETUNE) --data data/hard-s65 --init-weights runs/twelfth/shipped.pt
# the fourteenth: the same from the thirteenth, with frames of the flash, docking and earth
# worlds drawn apart again beside the thirteenth's
FITS66 := $(FSNET_FINETUNE) --data data/hard-s66 --init-weights runs/thirteenth/shipped.pt
# the fifteenth: two fine-tunes of the fourteenth on new frames of six worlds drawn apart
FITS67 := $(FSNET_FINETUNE) --init-weights runs/fourteenth/shipped.pt --lr 3e-4 --seed 67
# the sixteenth: two fine-tunes of the fifteenth on the second of those sets at a third the rate
FITS68 := $(FSNET_FINETUNE) --data data/hard2-s67 --init-weights runs/fifteenth/shipped.pt \
	--lr 1e-4
# the frames of one world alone for those fine-tunes: one view of each of 800 new models, both
# render styles; each round gives the world, the seed and the folder
WORLD_FRAMES := $(VENV)/bin/sdc-data generate --models 800 --views 1 --size 1024 \
	--styles ours pbr --only-splits train val --workers 1 --quiet
model: $(STAMP)
	$(VENV)/bin/sdc-data generate --out data/mixed --models 126 --views 40 --world mixed --seed 0
	mkdir -p runs/previous && git show $(PREVIOUS):models/sdcnet.pt > runs/previous/sdcnet.pt
	$(FIT) --out $(RUN) --warm-start runs/previous/sdcnet.pt --fsnet-epochs 1 --epochs 0 --lr 1e-3 \
		--seed 0
	$(FIT) --out $(RUN)b --init-weights $(RUN)/last.pt --fsnet-epochs 3 --epochs 3 --lr 7e-4 --seed 1
	$(FIT) --out $(RUN)c --init-weights $(RUN)b/best.pt --fsnet-epochs 3 --epochs 0 --lr 5e-4 --seed 2
	$(VENV)/bin/sdc-train ship --checkpoint $(RUN)c/best_stage1.pt --out $(RUN)c/shipped.pt
	$(VENV)/bin/sdc-train calibrate --checkpoint $(RUN)c/shipped.pt --data data/mixed --split val \
		--edge-weight 0 --out $(RUN)c/calibrated.pt
	$(VENV)/bin/sdc-train calibrate --checkpoint $(RUN)c/calibrated.pt --data data/mixed \
		--split val --edge-weight 0.5 --out $(RUN)c/sigma.pt
	$(VENV)/bin/sdc-data generate --out data/mixed-v12 --models 126 --views 12 --world mixed \
		--seed 0 --only-splits train val
	$(FIT12) --out runs/v4 --warm-start $(RUN)c/sigma.pt --fsnet-epochs 5 --lr 1e-3 --seed 3 \
		--val-samples 40
	$(FIT12) --out runs/v4b --init-weights runs/v4/best_stage1.pt --fsnet-epochs 14 --lr 5e-4 \
		--seed 4
	$(FIT12) --out runs/v4c --init-weights runs/v4b/best_stage1.pt --fsnet-epochs 6 --lr 3e-4 \
		--iou-over tile --seed 5
	$(VENV)/bin/sdc-train ship --checkpoint runs/v4c/best_stage1.pt --out runs/v4c/shipped.pt
	$(VENV)/bin/sdc-train calibrate --checkpoint runs/v4c/shipped.pt --data data/mixed --split val \
		--edge-weight 0 --out runs/v4c/calibrated.pt
	$(VENV)/bin/sdc-train calibrate --checkpoint runs/v4c/calibrated.pt --data data/mixed \
		--split val --edge-weight 0.5 --out runs/v4c/sigma.pt
	$(VENV)/bin/sdc-data generate --out data/mixed-s1 --models 126 --views 10 --world mixed \
		--seed 1 --only-splits train val
	$(FITS1) --out runs/v5 --init-weights runs/v4c/sigma.pt --fsnet-epochs 6 --lr 3e-4 --seed 6 \
		--workers 2
	$(VENV)/bin/sdc-train ship --checkpoint runs/v5/best_stage1.pt --out runs/v5/shipped.pt
	$(FITS1) --out runs/v6 --init-weights runs/v5/shipped.pt --fsnet-epochs 8 --lr 2e-4 --seed 7
	$(VENV)/bin/sdc-train ship --checkpoint runs/v6/best_stage1.pt --out runs/v6/shipped.pt
	$(VENV)/bin/sdc-data generate --out data/mixed-s2 --models 126 --views 8 --world mixed \
		--seed 2 --only-splits train val
	$(FITS2) --out runs/v8 --warm-start runs/v6/shipped.pt --fsnet-epochs 12 --lr 5e-4 --seed 8 \
		--workers 1
	$(VENV)/bin/sdc-train ship --checkpoint runs/v8/best_stage1.pt --out runs/v8/shipped.pt
	$(VENV)/bin/sdc-data generate --out data/mixed-s4 --models 126 --views 8 --world mixed \
		--seed 4 --only-splits train val
	$(FITS4) --out runs/v10 --init-weights runs/v8/shipped.pt --fsnet-epochs 10 --lr 3e-4 \
		--seed 10 --workers 1 --val-samples 72
	$(VENV)/bin/sdc-train ship --checkpoint runs/v10/best_stage1.pt --out runs/v10/shipped.pt
	-timeout 150 $(VENV)/bin/sdc-data generate --out data/mixed-s5 --models 800 --views 6 \
		--world mixed --seed 5 --only-splits train val --workers $(GPU_WORKERS) --quiet
	$(VENV)/bin/sdc-data close data/mixed-s5
	$(FITS5) --out runs/v11 --init-weights runs/v10/shipped.pt --fsnet-epochs 8 --lr 3e-4 --seed 11
	$(VENV)/bin/sdc-train ship --checkpoint runs/v11/best_stage1.pt --out runs/eighth/shipped.pt
	-timeout 220 $(VENV)/bin/sdc-data generate --out data/mixed-s7 --models 800 --views 6 \
		--world mixed --seed 7 --only-splits train val --workers $(GPU_WORKERS) --quiet
	$(VENV)/bin/sdc-data close data/mixed-s7
	-timeout 270 $(FITS7) --out runs/v14 --lr 3e-4 --seed 11 & \
		timeout 270 $(FITS7) --out runs/v15 --lr 1e-4 --seed 12; wait
	$(VENV)/bin/sdc-train average --checkpoints runs/eighth/shipped.pt runs/v14/best_stage1.pt \
		runs/v15/best_stage1.pt --out runs/ninth/shipped.pt
	$(VENV)/bin/sdc-data generate --out data/mixed-s10 --models 800 --views 3 --size 1024 \
		--world mixed --seed 10 --only-splits train val --workers 2 --quiet
	$(FITS10) --out runs/s59a --lr 3e-4 --seed 59
	$(VENV)/bin/sdc-train average --checkpoints runs/ninth/shipped.pt runs/s59a/best_stage1.pt \
		--out runs/tenth/shipped.pt
	$(VENV)/bin/sdc-data generate --out data/mixed-s62 --models 800 --views 3 --size 1024 \
		--world mixed --seed 62 --styles ours pbr --only-splits train val --workers 2 --quiet
	$(FITS62) --out runs/s62a --lr 3e-4 --seed 62
	$(VENV)/bin/sdc-train average --checkpoints runs/tenth/shipped.pt runs/s62a/best_stage1.pt \
		--out runs/eleventh/shipped.pt
	# the frames each generation had rendered when it was stopped (44 and 30 min on 2 cores):
	# 1551 and 518; the flash world's 686 were all rendered
	-timeout 2640 $(VENV)/bin/sdc-data generate --out data/mixed-s63 --models 800 --views 3 \
		--size 1024 --world mixed --seed 63 --styles ours pbr --only-splits train val \
		--workers 2 --quiet
	$(VENV)/bin/sdc-data close data/mixed-s63
	for w in flash docking; do timeout 1800 $(WORLD_FRAMES) --out data/$$w-s64 --world $$w \
		--seed 64 & done; wait
	$(VENV)/bin/sdc-data close data/flash-s64
	$(VENV)/bin/sdc-data close data/docking-s64
	$(VENV)/bin/sdc-data merge --out data/hard-s64 data/mixed-s63 data/flash-s64 data/docking-s64
	$(FITS64) --out runs/s64a --lr 3e-4 --seed 64
	$(VENV)/bin/sdc-train average --checkpoints runs/eleventh/shipped.pt runs/s64a/best_stage1.pt \
		--out runs/twelfth/shipped.pt
	# wide-multibeam's and sun-moon's 686 frames were all rendered (15 and 13 min, the second
	# after the first); `any`'s generation was stopped at 30 min with 583
	timeout 1800 $(WORLD_FRAMES) --out data/any-s65 --world any --seed 65 & \
	for w in wide-multibeam sun-moon; do $(WORLD_FRAMES) --out data/$$w-s65 --world $$w \
		--seed 65; done; wait
	$(VENV)/bin/sdc-data close data/any-s65
	$(VENV)/bin/sdc-data merge --out data/hard-s65 data/mixed-s63 data/flash-s64 \
		data/docking-s64 data/wide-multibeam-s65 data/any-s65 data/sun-moon-s65
	$(FITS65) --out runs/s65a --lr 3e-4 --seed 65
	$(VENV)/bin/sdc-train average --checkpoints runs/twelfth/shipped.pt runs/s65a/best_stage1.pt \
		--out runs/thirteenth/shipped.pt
	# flash's and earth's 686 frames were all rendered (13 and 12 min, earth's after flash's);
	# docking's generation was stopped at 30 min with 658
	timeout 1800 $(WORLD_FRAMES) --out data/docking-s66 --world docking --seed 66 & \
	for w in flash earth; do $(WORLD_FRAMES) --out data/$$w-s66 --world $$w --seed 66; done; \
	wait
	$(VENV)/bin/sdc-data close data/docking-s66
	$(VENV)/bin/sdc-data merge --out data/hard-s66 data/mixed-s63 data/flash-s64 \
		data/docking-s64 data/wide-multibeam-s65 data/any-s65 data/sun-moon-s65 \
		data/flash-s66 data/docking-s66 data/earth-s66
	$(FITS66) --out runs/s66a --lr 3e-4 --seed 66
	# the fine-tune counted twice: its weight two thirds of the mean
	$(VENV)/bin/sdc-train average --checkpoints runs/thirteenth/shipped.pt runs/s66a/best_stage1.pt \
		runs/s66a/best_stage1.pt --out runs/fourteenth/shipped.pt
	# flash's and wide-multibeam's 686 frames were all rendered (17 and 13 min, the second after
	# the first, beside docking's, stopped at 30 min with 494); `any`'s generation was stopped at
	# 20 min with 244; earth's and sun-moon's 686 each took 18 and 17 min side by side
	timeout 1800 $(WORLD_FRAMES) --out data/docking-s67 --world docking --seed 67 & \
	for w in flash wide-multibeam; do $(WORLD_FRAMES) --out data/$$w-s67 --world $$w \
		--seed 67; done; wait
	-timeout 1200 $(WORLD_FRAMES) --out data/any-s67 --world any --seed 67
	$(VENV)/bin/sdc-data close data/docking-s67
	$(VENV)/bin/sdc-data close data/any-s67
	for w in earth sun-moon; do $(WORLD_FRAMES) --out data/$$w-s67 --world $$w \
		--seed 67 & done; wait
	$(VENV)/bin/sdc-data merge --out data/hard-s67 data/flash-s67 data/docking-s67 \
		data/wide-multibeam-s67 data/any-s67
	$(VENV)/bin/sdc-data merge --out data/hard2-s67 data/flash-s67 data/docking-s67 \
		data/wide-multibeam-s67 data/any-s67 data/earth-s67 data/sun-moon-s67
	$(FITS67) --data data/hard-s67 --out runs/s67a
	$(FITS67) --data data/hard2-s67 --out runs/s67b
	# the fourteenth counted twice: half the mean, each fine-tune a quarter
	$(VENV)/bin/sdc-train average --checkpoints runs/fourteenth/shipped.pt \
		runs/fourteenth/shipped.pt runs/s67a/best_stage1.pt runs/s67b/best_stage1.pt \
		--out runs/fifteenth/shipped.pt
	$(FITS68) --out runs/s68a --seed 68
	$(FITS68) --out runs/s69a --seed 69 --fsnet-epochs 6
	# the fifteenth counted twice again
	$(VENV)/bin/sdc-train average --checkpoints runs/fifteenth/shipped.pt \
		runs/fifteenth/shipped.pt runs/s68a/best_stage1.pt runs/s69a/best_stage1.pt \
		--out models/sdcnet.pt
	$(MAKE) reports

## reports: evaluate the shipped checkpoint beside the previous model (git $(PREVIOUS), run by its
## own version of the pipeline: benchmarks/previous_model.py) and the classical fill on the
## paper's test split, the real meshes and every condition of the robustness suite; export it
## with its parity check; refresh the galleries and the card
.PHONY: reports
PREVIOUS_ANSWERS := runs/previous/answers
# the third shipped model (git $(THIRD)), the one this model's FSNet grew from: same pipeline
THIRD ?= ab691bf
THIRD_ONNX := runs/third/third-model.onnx
MESHES ?= ../shared/real-meshes
CONDITIONS := paper other-renderer earth sun-moon wide-multibeam flash docking docking-2048 narrow-far any
$(THIRD_ONNX):
	mkdir -p $(dir $@) && git show $(THIRD):models/sdcnet.onnx > $@
# the eighth shipped model (git $(EIGHTH)), the one this model averages with its fine-tunes
EIGHTH ?= 165485f
EIGHTH_ONNX := runs/eighth/eighth-model.onnx
$(EIGHTH_ONNX):
	mkdir -p $(dir $@) && git show $(EIGHTH):models/sdcnet.onnx > $@
reports: $(STAMP) $(THIRD_ONNX)
	$(VENV)/bin/sdc-data generate --out data/paper --models 126 --views 64 --size 1024 --seed 0 \
		--only-splits test
	$(VENV)/bin/sdc-train ship --checkpoint models/sdcnet.pt --out runs/ablation/plane-alone.pt \
		--zero fdcnet.head
	$(PY) -m benchmarks.previous_model --commit $(PREVIOUS) --data data/paper --split test \
		--limit 288 --out $(PREVIOUS_ANSWERS)/paper
	$(VENV)/bin/sdc-eval evaluate --checkpoint models/sdcnet.pt runs/ablation/plane-alone.pt \
		--names sdcnet "its plane fit alone" --onnx $(THIRD_ONNX) \
		--answers "previous model=$(PREVIOUS_ANSWERS)/paper" \
		--data data/paper --split test --floor --limit 288 --out models/eval_test.json \
		--title "Synthetic test split, the paper's camera and LIDAR (18 unseen models, every fourth frame)"
	$(VENV)/bin/sdc-export --checkpoint models/sdcnet.pt --out models/sdcnet.onnx \
		--metrics models/eval_test.json
	$(PY) -m tests.test_answers_unchanged --write
	$(VENV)/bin/sdc-eval evaluate --onnx models/sdcnet.onnx --data data/paper --split test --limit 288 \
		--out models/eval_test_onnx.json \
		--title "Synthetic test split through onnxruntime (the service's numbers, every fourth frame)"
	$(VENV)/bin/sdc-data generate --out data/real --models 0 --views 8 --seed 0 --split 0,0,0 \
		--meshes $(MESHES)
	$(PY) -m benchmarks.previous_model --commit $(PREVIOUS) --data data/real --out $(PREVIOUS_ANSWERS)/real
	$(VENV)/bin/sdc-eval real --onnx models/sdcnet.onnx $(THIRD_ONNX) --floor --out docs/real \
		--answers "previous model=$(PREVIOUS_ANSWERS)/real"
	for c in $(CONDITIONS); do $(VENV)/bin/sdc-data generate --out data/robustness/$$c --models 126 \
		--views 2 --seed 0 --world $$c --meshes $(MESHES) --only-splits test real || exit 1; done
	$(PY) -m benchmarks.previous_model --commit $(PREVIOUS) --data data/robustness \
		--out $(PREVIOUS_ANSWERS)/robustness
	$(VENV)/bin/sdc-eval robustness --onnx models/sdcnet.onnx $(THIRD_ONNX) --views 2 \
		--out docs/robustness \
		--answers "previous model=$(PREVIOUS_ANSWERS)/robustness"
	$(MAKE) card

## bench: regenerate the benchmark tables and plots in docs/benchmarks/ (needs data/paper and
## data/robustness from `make reports`; FP16/INT8 variants are made in runs/variants, not shipped)
.PHONY: bench
bench: $(STAMP) $(THIRD_ONNX) $(EIGHTH_ONNX)
	$(PY) -m benchmarks.pipeline_latency --onnx models/sdcnet.onnx --data data/robustness \
		--beside $(EIGHTH_ONNX) $(THIRD_ONNX) --previous $(PREVIOUS)
	$(VENV)/bin/sdc-export --checkpoint models/sdcnet.pt --out runs/variants/sdcnet.onnx \
		--variants fp16 int8 --calibration-data data/mixed
	$(PY) -m benchmarks.model_latency --checkpoint models/sdcnet.pt --onnx runs/variants/sdcnet.onnx
	$(PY) -m benchmarks.accuracy_speed --checkpoint models/sdcnet.pt --onnx runs/variants/sdcnet.onnx \
		--data data/paper --split test --limit 192
	$(PY) -m benchmarks.service_latency --requests 60
	$(PY) -m benchmarks.first_frames --conditions docking-2048 any --frames 8 --starts 3
	$(PY) -m benchmarks.load --requests 2000 --concurrency 32
	$(PY) -m benchmarks.mask_trust --onnx models/sdcnet.onnx --limit 288 \
		--sets $(addprefix data/robustness/,$(CONDITIONS)) data/real data/paper:test

## ablation: the paper's Tables 4 and 5 on the mixed world with the cpu recipe (needs $(RUN)c from
## `make model`). Table 5: every fusion variant trains stage 2 on $(RUN)c's frozen FSNet (the
## baseline has none), evaluated beside $(RUN)c's own SDCNet. Table 4: FSNet on gray or sparse
## alone, stage 1 only, against $(RUN)c's stage 1 on both.
.PHONY: ablation
FUSIONS := fsnet fsnet+cca fsnet+sa
ablation: $(STAMP)
	for v in $(FUSIONS); do $(VENV)/bin/sdc-train fit --data data/mixed --out runs/ablation-$$v \
		--preset $(PRESET) --variant $$v --init-segmentation $(RUN)c/best_stage1.pt || exit 1; done
	$(VENV)/bin/sdc-train fit --data data/mixed --out runs/ablation-baseline --preset $(PRESET) \
		--variant baseline
	for i in gray sparse; do $(VENV)/bin/sdc-train fit --data data/mixed --out runs/ablation-fsnet-$$i \
		--preset $(PRESET) --fsnet-inputs $$i --epochs 0 || exit 1; done
	$(VENV)/bin/sdc-eval evaluate --data data/paper --split test --limit 288 --out models/eval_ablation.json \
		--checkpoint runs/ablation-baseline/best.pt $(foreach v,$(FUSIONS),runs/ablation-$(v)/best.pt) $(RUN)c/shipped.pt \
		--names "(a) baseline: guided conv., no FSNet" "(b) + FSNet" "(c) + FSNet + CCA" "(d) + FSNet + SA" "(e) + FSNet + CCA + SA = SDCNet" \
		--title "Table 5 ablation, test split: each component added to the GuideNet-style baseline (cpu recipe, one seed; every fourth test frame)"
	$(VENV)/bin/sdc-eval evaluate --data data/paper --split test --segmentation-only \
		--out models/eval_fsnet_inputs.json \
		--checkpoint runs/ablation-fsnet-gray/best_stage1.pt runs/ablation-fsnet-sparse/best_stage1.pt $(RUN)c/best_stage1.pt \
		--names "FSNet on gray" "FSNet on sparse depth" "FSNet on both" \
		--title "Table 4 ablation, test split: FSNet's inputs (8 epochs of stage 1 each, mask metrics only)"
	$(MAKE) card

## ablation-fsnet-growth: what FSNet's width bought apart from its training (needs runs/v4c and
## data/mixed-v12 from `make model`, runs/third/third-model.pt): the 5.9k FSNet trained by the
## same three runs, then both masks per condition of the robustness suite (the card's notes)
.PHONY: ablation-fsnet-growth
NARROW := $(VENV)/bin/sdc-train fit --data data/mixed-v12 --preset $(PRESET) --iou-loss 1 \
	--workers 2 --fsnet-growth 1 --epochs 0
ablation-fsnet-growth: $(STAMP) $(THIRD_ONNX)
	git show $(THIRD):models/sdcnet.pt > runs/third/third-model.pt
	$(NARROW) --out runs/ablation-fsnet-narrow --warm-start runs/third/third-model.pt \
		--fsnet-epochs 5 --lr 1e-3 --seed 3 --val-samples 40
	$(NARROW) --out runs/ablation-fsnet-narrow-b --init-weights runs/ablation-fsnet-narrow/best_stage1.pt \
		--fsnet-epochs 14 --lr 5e-4 --seed 4
	$(NARROW) --out runs/ablation-fsnet-narrow-c \
		--init-weights runs/ablation-fsnet-narrow-b/best_stage1.pt --fsnet-epochs 6 --lr 3e-4 \
		--iou-over tile --seed 5
	$(VENV)/bin/sdc-eval robustness --checkpoint runs/v4c/best_stage1.pt \
		runs/ablation-fsnet-narrow-c/best_stage1.pt runs/third/third-model.pt \
		--names "wide, 25 epochs" "narrow, 25 epochs" "third model" --views 2 --gallery 0 \
		--out runs/ablation-fsnet-growth

## card: rewrite models/MODEL_CARD.md from the checkpoint and the evaluation reports
.PHONY: card
card: $(STAMP)
	$(VENV)/bin/sdc-eval card --checkpoint models/sdcnet.pt --onnx models/sdcnet.onnx \
		--report models/eval_test.json models/eval_test_onnx.json \
		$(wildcard models/eval_ablation.json models/eval_fsnet_inputs.json) \
		docs/real/real_spacecraft.json --robustness docs/robustness/robustness.json \
		--notes models/NOTES.md --out models/MODEL_CARD.md
