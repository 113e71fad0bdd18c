# Two entry points for a fresh clone (see README):
#   make demo   install into .venv, then read the shipped recording (examples/duck_toss_scene) with predict
#   make test   install into .venv, then lint, format check and the test suite (CPU only)
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
DEMO_OUT ?= demo_out

.PHONY: install demo test lint bench model model-crop model-cnn gs-model gs-model-crop masks-model clean

install: $(VENV)/.installed

# The CPU build of torch is pinned here, not in pyproject: an open `torch` requirement would pull a
# multi-GB CUDA build on a machine that has no torch yet.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $@

demo: install
	$(BIN)/reconphys demo --out $(DEMO_OUT)

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports

test: lint
	$(BIN)/python -m pytest -q

bench: install
	$(BIN)/python benchmarks/bench_simulator.py
	$(BIN)/python benchmarks/bench_renderer.py

# The shipped physics predictor's recipe (docs/training.md "Stretched meshes"; ~2.7 h on 2 CPU
# cores): pybullet's meshes (the meshes extra), the held-out test set data/pyb, three draws of drops
# and tosses of every other mesh rendered at 64 px (seeds 3, 13 and 23) and a fourth of them
# stretched by up to 4x (seed 33), five
# silhouette-track networks (seeds 0-4) trained supervised on the observables at 32 px, the
# factors of their belief's spread chosen on 200 drops and tosses of the validation meshes, their
# ensemble copied into the package's weights. The previous CNN recipe (cpu_small) is `make model-cnn`.
model: install
	$(BIN)/python -m pip install -q -e '.[meshes]'
	$(BIN)/reconphys make-data --config configs/data_pyb.toml --workers 2 --out data/pyb
	$(BIN)/python benchmarks/held_out_meshes.py data/pyb data/pybullet_meshes
	$(BIN)/reconphys make-data --config configs/data_pybullet.toml --resolution 64 --workers 2 \
	    --out data/pybullet64
	$(BIN)/reconphys make-data --config configs/data_pybullet.toml --resolution 64 --seed 13 \
	    --workers 2 --out data/pybullet64_s13
	$(BIN)/reconphys make-data --config configs/data_pybullet.toml --resolution 64 --seed 23 \
	    --workers 2 --out data/pybullet64_s23
	$(BIN)/reconphys make-data --config configs/data_pybullet.toml --resolution 64 --seed 33 \
	    --stretch 4 --workers 2 --out data/pybullet64_x33
	$(BIN)/reconphys train configs/track_pybullet.toml --no-progress
	$(BIN)/python benchmarks/held_out_meshes.py --validation data/pybullet_meshes data/val_meshes
	$(BIN)/reconphys make-data --config configs/data_small.toml --source data/val_meshes \
	    --toss-fraction 0.5 --objects 0 --test-objects 100 --test-samples-per-object 2 --seed 71 \
	    --workers 2 --out data/val200
	$(BIN)/python benchmarks/network_intervals.py data/val200 --model runs/track_pybullet --write
	cp runs/track_pybullet/model.safetensors src/reconphys/weights/physics_predictor.safetensors
	cp runs/track_pybullet/model.json src/reconphys/weights/physics_predictor.json

# The shipped network of object crops, what predict reads any recording but the plain look with
# (docs/training.md "Object-centric input"; ~1.5 h on 2 CPU cores after `make model`'s data/pyb):
# realistic-look drops and tosses of the same training meshes (two seeds, 2 each), five track
# networks of object crops, their ensemble copied into the package's weights.
model-crop: install
	$(BIN)/python -m pip install -q -e '.[meshes]'
	$(BIN)/python benchmarks/held_out_meshes.py data/pyb data/pybullet_meshes
	$(BIN)/reconphys make-data --config configs/data_real_pybullet.toml --workers 2 \
	    --out data/real_pybullet
	$(BIN)/reconphys make-data --config configs/data_real_pybullet.toml --seed 22 --workers 2 \
	    --out data/real_pybullet2
	$(BIN)/reconphys train configs/track_realistic.toml --no-progress
	cp runs/track_realistic/model.safetensors src/reconphys/weights/physics_predictor_crop.safetensors
	cp runs/track_realistic/model.json src/reconphys/weights/physics_predictor_crop.json

# The CNN predictor shipped until 2026-11-25 (docs/training.md "Results"; ~75 min): the cpu_small
# data, supervised pre-training on the observables, a mixed photometric fine-tune (runs/cpu_small_mixed).
CPU_SMALL := configs/cpu_small.toml objective.supervised_target=observables --no-progress
model-cnn: install
	$(BIN)/reconphys make-data --config configs/data_small.toml --out data/cpu_small
	$(BIN)/reconphys train $(CPU_SMALL) objective.kind=supervised train.steps=2000 \
	    train.batch_size=8 train.checkpoint_every=250 train.out=runs/cpu_small_sup_obs
	$(BIN)/reconphys train $(CPU_SMALL) objective.kind=mixed train.init=runs/cpu_small_sup_obs \
	    optim.lr=3e-4 optim.warmup_steps=0 train.steps=150 train.checkpoint_every=25 \
	    train.log_every=5 train.out=runs/cpu_small_mixed

# The shipped 3DGS predictor's recipe (docs/usage.md "The 3DGS predictor"): frame 0 of the
# cpu_small data (made by `make model-cnn` above), 1500 steps × 4 samples (configs/gs_cpu_small.toml).
gs-model: install
	$(BIN)/reconphys train-gs --config configs/gs_cpu_small.toml --threads 1 --no-progress
	cp runs/gs_cpu_small/model.safetensors src/reconphys/weights/gaussian_predictor.safetensors
	cp runs/gs_cpu_small/model.json src/reconphys/weights/gaussian_predictor.json

# The shipped object-centric 3DGS predictor's recipe (docs/usage.md "The 3DGS predictor"; ~55 min
# on 2 CPU cores after `make model`'s data/pyb): realistic-look drops of 949 pybullet meshes at
# 128 px (none of data/pyb's test meshes; 23 min), 3000 steps of train-gs on 48-px object crops
# (configs/gs_crop.toml; 18 min), then 1500 more from there with the object's true distance
# (configs/gs_crop_tune.toml, ~9 min; docs/usage.md "One object, not a hedge"). The shipped weights' second
# stage ran on 600 drops of that kind with the validation sets' meshes left out as well (their
# model.json records both stages).
gs-model-crop: install
	$(BIN)/python -m pip install -q -e '.[meshes]'
	$(BIN)/python benchmarks/held_out_meshes.py data/pyb data/pybullet_meshes
	$(BIN)/reconphys make-data --config configs/data_gs_realistic.toml --workers 2 \
	    --out data/gs_realistic
	$(BIN)/reconphys train-gs --config configs/gs_crop.toml --no-progress
	$(BIN)/reconphys train-gs --config configs/gs_crop_tune.toml --no-progress
	cp runs/gs_crop_tune/model.safetensors src/reconphys/weights/gaussian_predictor_crop.safetensors
	cp runs/gs_crop_tune/model.json src/reconphys/weights/gaussian_predictor_crop.json

# The shipped mask segmenter's recipe (docs/usage.md "Masks without a clean plate"; two trainings of
# 8000 steps, the first measured at about 1 h 35 min on 2 CPU cores, plus the data): realistic-look videos of 60 pybullet meshes (20 more held out) and 80 procedural
# shapes at 96 px, as many again in the vivid look (2026-11-27), every held-out and validation
# mesh left out (configs/masks_held_out.txt), 8000 steps of train-masks. The shipped segmenter is
# an ensemble of two such networks (2026-11-28): the first's vivid clips have high-contrast floors
# in half of them, the second's none; then both go on for 1,500 steps with a hand in view
# (2026-11-28, later; about 40 min for the two), then for 1,000 with grey objects (2026-12-02);
# the first for 1,000 more with pybullet's renders beside them (2026-12-03).
masks-model: install
	$(BIN)/python -m pip install -q -e '.[meshes]'
	$(BIN)/reconphys make-data --source pybullet --scene realistic --objects 60 \
	    --samples-per-object 2 --test-objects 20 --test-samples-per-object 2 --resolution 96 \
	    --seed 3 --workers 2 --out data/seg_pyb
	$(BIN)/reconphys make-data --source procedural --scene realistic --objects 80 \
	    --samples-per-object 2 --test-objects 0 --resolution 96 --seed 7 --workers 2 \
	    --out data/seg_proc
	$(BIN)/reconphys make-data --source pybullet --scene realistic --vivid-share 1 \
	    --contrast-share 0.5 --objects 60 --samples-per-object 2 --test-objects 0 \
	    --resolution 96 --seed 103 --workers 2 --out data/seg_vivid_pyb
	$(BIN)/reconphys make-data --source procedural --scene realistic --vivid-share 1 \
	    --contrast-share 0.5 --objects 80 --samples-per-object 2 --test-objects 0 \
	    --resolution 96 --seed 107 --workers 2 --out data/seg_vivid_proc
	$(BIN)/reconphys train-masks --data data/seg_pyb --data data/seg_proc \
	    --data data/seg_vivid_pyb --data data/seg_vivid_proc \
	    --exclude configs/masks_held_out.txt --out runs/masks --steps 8000 --no-progress
	cp runs/masks/model.safetensors src/reconphys/weights/mask_segmenter.safetensors
	cp runs/masks/model.json src/reconphys/weights/mask_segmenter.json
	$(BIN)/reconphys make-data --source pybullet --scene realistic --vivid-share 1 \
	    --objects 60 --samples-per-object 2 --test-objects 0 --resolution 96 --seed 103 \
	    --workers 2 --out data/seg_vivid_pyb_2
	$(BIN)/reconphys make-data --source procedural --scene realistic --vivid-share 1 \
	    --objects 80 --samples-per-object 2 --test-objects 0 --resolution 96 --seed 107 \
	    --workers 2 --out data/seg_vivid_proc_2
	$(BIN)/reconphys train-masks --data data/seg_pyb --data data/seg_proc \
	    --data data/seg_vivid_pyb_2 --data data/seg_vivid_proc_2 \
	    --exclude configs/masks_held_out.txt --out runs/masks_2 --steps 8000 --no-progress
	# both members then go on with hands in view (docs/usage.md "A hand in view"): 1,500 steps
	# from their weights on the first dataset and three with a hand letting the object go
	$(BIN)/reconphys make-data --source pybullet --scene realistic --hand-share 1 \
	    --vivid-share 0.5 --objects 40 --samples-per-object 2 --test-objects 0 --resolution 96 \
	    --seed 109 --workers 2 --out data/seg_hand_pyb
	$(BIN)/reconphys make-data --source procedural --scene realistic --hand-share 1 \
	    --vivid-share 0.5 --objects 40 --samples-per-object 2 --test-objects 0 --resolution 96 \
	    --seed 113 --workers 2 --out data/seg_hand_proc
	$(BIN)/reconphys make-data --source pybullet --scene realistic --hand-share 0.5 \
	    --vivid-share 1 --contrast-share 0.5 --objects 40 --samples-per-object 2 \
	    --test-objects 0 --resolution 96 --seed 127 --workers 2 --out data/seg_hand_vivid
	# then both go on with grey objects (docs/usage.md "Grey objects", 2026-12-02; their
	# lightness drawn black to white since 2026-12-03): 1,000 steps from the hand runs on grey
	# drops of pybullet meshes and procedural shapes, 30 pybullet meshes in colour and the
	# hand/vivid set (about 24 min for the two, one thread each)
	$(BIN)/reconphys make-data --source pybullet --scene realistic --objects 30 \
	    --samples-per-object 2 --test-objects 0 --resolution 96 --seed 3 --workers 2 \
	    --out data/seg_pyb30
	$(BIN)/reconphys make-data --source pybullet --scene realistic --grey-share 1 \
	    --vivid-share 0.5 --contrast-share 0.25 --hand-share 0.25 --objects 40 \
	    --samples-per-object 2 --test-objects 0 --resolution 96 --seed 131 --workers 2 \
	    --out data/seg_grey_pyb
	$(BIN)/reconphys make-data --source procedural --scene realistic --grey-share 1 \
	    --vivid-share 0.5 --hand-share 0.25 --objects 40 --samples-per-object 2 \
	    --test-objects 0 --resolution 96 --seed 137 --workers 2 --out data/seg_grey_proc
	for m in masks masks_2; do \
	    $(BIN)/reconphys train-masks --data data/seg_pyb --data data/seg_hand_pyb \
	        --data data/seg_hand_proc --data data/seg_hand_vivid \
	        --exclude configs/masks_held_out.txt --init runs/$$m --lr 0.0005 --steps 1500 \
	        --out runs/$${m}_hand --no-progress || exit 1; \
	    $(BIN)/reconphys train-masks --data data/seg_pyb30 --data data/seg_grey_pyb \
	        --data data/seg_grey_proc --data data/seg_hand_vivid \
	        --exclude configs/masks_held_out.txt --init runs/$${m}_hand --lr 0.0005 \
	        --steps 1000 --out runs/$${m}_hand_grey --no-progress || exit 1; \
	done
	# then the first member goes on with another engine's look (docs/usage.md "Another engine's
	# look in training", 2026-12-03): 1,000 steps from its grey run on the same mix and 400
	# pybullet drops of wheel meshes none held out, on three of the five floor/wall textures
	# (about 15 min for the renders, 15 for the training, one thread each)
	for s in 139 149; do \
	    $(BIN)/python benchmarks/other_engine.py render data/seg_engine_$$s --clips 200 \
	        --training-meshes 200 --seed $$s \
	        --textures checker_blue.png,checker_grid.jpg,tex256.png || exit 1; \
	done
	$(BIN)/reconphys train-masks --data data/seg_pyb30 --data data/seg_grey_pyb \
	    --data data/seg_grey_proc --data data/seg_hand_vivid --data data/seg_engine_139 \
	    --data data/seg_engine_149 --exclude configs/masks_held_out.txt \
	    --init runs/masks_hand_grey --lr 0.0005 --steps 1000 --out runs/masks_hand_grey_engine \
	    --no-progress
	# then both go on with a third renderer's look (docs/usage.md "A third renderer in training",
	# 2026-12-03, seventh session): 200 drops of wheel meshes path-traced by Mitsuba (half lit by
	# a sky), 1,000 steps each; the second member without pybullet's renders (about 40 min for
	# the renders, 17 for the training, one thread each)
	$(BIN)/python -m pip install -q mitsuba
	$(BIN)/python benchmarks/other_engine.py render data/seg_mitsuba_151 --clips 200 \
	    --training-meshes 200 --seed 151 --renderer mitsuba --spp 16 --size 96x96 \
	    --sky-share 0.5 --textures checker_blue.png,checker_grid.jpg,tex256.png
	$(BIN)/reconphys train-masks --data data/seg_pyb30 --data data/seg_grey_pyb \
	    --data data/seg_grey_proc --data data/seg_hand_vivid --data data/seg_engine_139 \
	    --data data/seg_engine_149 --data data/seg_mitsuba_151 \
	    --exclude configs/masks_held_out.txt --init runs/masks_hand_grey_engine --lr 0.0005 \
	    --steps 1000 --out runs/masks_hand_grey_engine_mitsuba --threads 1 --no-progress
	$(BIN)/reconphys train-masks --data data/seg_pyb30 --data data/seg_grey_pyb \
	    --data data/seg_grey_proc --data data/seg_hand_vivid --data data/seg_mitsuba_151 \
	    --exclude configs/masks_held_out.txt --init runs/masks_2_hand_grey --lr 0.0005 \
	    --steps 1000 --out runs/masks_2_hand_grey_mitsuba --threads 1 --no-progress
	cp runs/masks_hand_grey_engine_mitsuba/model.safetensors src/reconphys/weights/mask_segmenter.safetensors
	cp runs/masks_hand_grey_engine_mitsuba/model.json src/reconphys/weights/mask_segmenter.json
	cp runs/masks_2_hand_grey_mitsuba/model.safetensors src/reconphys/weights/mask_segmenter_2.safetensors
	cp runs/masks_2_hand_grey_mitsuba/model.json src/reconphys/weights/mask_segmenter_2.json

clean:
	rm -rf $(VENV) $(DEMO_OUT) .pytest_cache .ruff_cache
