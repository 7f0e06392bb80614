"""Social navigation: RGB-D scene flow, crowd features, IRL cost, planners (seed 02, Kim & Pineau 2016)."""
