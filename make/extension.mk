# Blender extension (include from the Makefile: `include make/extension.mk`).
#   make extension                              all platforms listed in blender_manifest.toml
#   make extension EXT_PLATFORMS=linux-x64      only some (comma-separated Blender platform names)
#   make extension-validate                     stage + validate the manifest, no wheels needed
# Wheels are downloaded once into ./wheels (gitignored); zips go to dist/.
EXT_PLATFORMS ?=
EXT_OUT       ?= dist

.PHONY: extension extension-validate

extension: $(STAMP)
	$(VPY) make/build_extension.py --out $(EXT_OUT) $(if $(EXT_PLATFORMS),--platforms $(EXT_PLATFORMS))

extension-validate: $(STAMP)
	$(VPY) make/build_extension.py --stage-only
