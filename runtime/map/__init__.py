"""The sparse global semantic map: model, lifting, fusion, floor, extent, refinement."""
