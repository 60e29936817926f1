"""Live operation: tracking and mapping on their own threads (and CUDA streams), frames dropped to keep up."""

from sgs_slam_core.live.pipeline import MapJob, PipelineStats, SlamPipeline

__all__ = ["MapJob", "PipelineStats", "SlamPipeline"]
