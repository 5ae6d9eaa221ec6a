"""RGBD-HDR estimator (paper section 4.1): disparity D and HDR exponent E from one 8-bit frame.

Modules, one job each (importing this package loads nothing heavy; torch is imported by the
modules that need it):

* :mod:`.bilateral` - differentiable trilinear slicing of a bilateral grid over luma;
* :mod:`.unet` - the U-Net (3 E channels + an N-bin bilateral grid for D);
* :mod:`.losses` - rendering, adjusted rendering (triplets), smoothness, eq. 7;
* :mod:`.align` - ECC alignment of aperture-bracketed photos;
* :mod:`.data` - training samples from harness clips and bracketed photos;
* :mod:`.train` - the resumable training job behind ``rvr train``;
* :mod:`.cache` - the per-clip cache (one EXR per frame + meta.json);
* :mod:`.infer` - per-frame inference, external depth, the job behind ``rvr estimate``.
* :mod:`.evaluate` - scores weights against ground truth (``rvr eval-estimator``).
"""
