"""The SLAM algorithm, stage by stage, reading like the papers.

- :mod:`~gsslam.slam.pipeline`: :class:`Pipeline` wires the stages (``process`` per frame, ``finish``).
- :mod:`~gsslam.slam.chains`: chains of submaps (one graph each), keyframe records, tracking events.
- :mod:`~gsslam.slam.cross_flow`: GaussianFlow's flow-BA feed (flow factors between keyframes of
  consecutive submaps; the same flows supervise the Gaussian map).
- :mod:`~gsslam.slam.map_stage`: the Gaussian map kept in step with the graphs, and SING3R's feedback
  (rendered depth of the shared frame into the next submap, depth priors into the graph).
- :mod:`~gsslam.slam.loop_stage`: loop detection, verification, add / check / remove in the graph.
"""
