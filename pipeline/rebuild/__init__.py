"""The nightly rebuild: plan what changed, ingest it, run the stages, assemble a new
warehouse and publish it atomically beside the previous one."""
