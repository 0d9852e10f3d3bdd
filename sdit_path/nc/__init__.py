"""NC stage: controller-neutral programs, the post-processor registry, lint helpers,
read-back of emitted programs and atomic output."""
