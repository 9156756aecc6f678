"""Reading lab image series and writing results: the edge of gridstrain that touches files.

Two private modules, re-exported here: ``_series`` (reading frames and masks)
and ``_files`` (writing gridstrain's own files, and reading them back).

Input
    :func:`open_series` turns a single image, a multi-page TIFF stack, a directory,
    a glob pattern or a list of files into a :class:`FrameSeries`: a validated,
    ordered list of 2-D grey-level frames that are read one at a time (memory is
    bounded by one frame whatever the length of the series). TIFF files are read
    with ``tifffile``, page by page (packed 10/12-bit and LZW, deflate or zstd
    compressed pages through ``imagecodecs``); PNG, BMP and JPEG files with
    ``imageio``; videos through PyAV (the ``video`` extra); Phantom cine and Photron
    MRAW records of high-speed cameras from their published layouts, frame by frame,
    every header size and offset checked against the file first, their significant
    bits as the bit depth and their frame times from the trigger
    (:attr:`FrameSeries.times`, :attr:`FrameSeries.frame_rate`,
    :attr:`FrameSeries.trigger_frame`). Each format is registered once
    (:class:`ImageFormat`, :func:`register_format`: its suffixes, leading bytes, header
    scan, frame reader and what it holds), and found by the file's suffix. Colour frames are
    read as their luminance (:func:`to_luminance`,
    ITU-R BT.709 weights) and JPEG files with a note on their lossy compression
    (:attr:`FrameSeries.notes`). :func:`read_mask` reads a specimen mask, grey,
    1-bit or colour (:mod:`gridstrain.conventions`, Masks); :func:`roi_mask`
    makes one from a rectangle or a polygon. :func:`record_numbering` reads the frame
    numbers of a record saved one file per frame from the file names and names its
    breaks (:class:`FrameGap`: missing, off-step or out-of-order numbers; repeated
    numbers are refused).
    :func:`read_loads` reads a testing
    machine's export as it comes (delimiter, decimal comma, preamble, units in the
    header, encoding) and joins its log to the states by time (:class:`LoadsFile`
    names its columns and the log's offset; :class:`LoadTable` records how).

Grey levels and bit depth
    Frames are returned in *raw* grey levels, the values stored in the files.
    Cameras of the PCO Sensicam class store their 12-bit output in 16-bit files
    multiplied by 2**4 (the founding paper, Fig. 1), so that raw values are
    multiples of 16 up to 4095 * 16 = 65520. :func:`open_series` detects this and
    records it as ``scale = 16`` and ``bit_depth = 12``; nothing is divided
    silently. Pass ``to_sensor_units=True`` to the readers to get grey levels of
    the sensor (raw / ``scale``), the unit in which the sensor noise model of
    :mod:`gridstrain.models.synthetic` (``Var = K l + L``) is written.

Output
    Every file is written atomically (:func:`atomic_path`): to a temporary file in
    the destination directory, renamed onto the destination only when complete,
    so that an interrupted run never leaves a truncated result behind. An existing
    file is replaced only with ``overwrite=True``. Files made by other libraries
    (HDF5, TIFF, PNG) are built in memory and written with plain file calls
    (:func:`write_atomic`): a full disk or a file size limit is then one
    ``OSError`` naming the file (:func:`space_error`), with nothing left behind,
    never a crash inside the library. In an output directory
    (:class:`OutputDirectory`) a marker file lists what gridstrain wrote, and only
    those files are ever replaced; the command line lists its single output files
    (``-o maps.h5``, a report) in the marker of their folder
    (:func:`record_outputs`), and ``--overwrite`` replaces only a file
    :func:`written_by_gridstrain` recognises. :func:`write_hdf5` writes
    compressed, checksummed HDF5 with units and JSON-encoded metadata;
    :func:`write_csv` writes exact decimal columns; :func:`write_tiff_series`
    writes a folder of numbered single-page TIFFs such as a camera produces.
    :func:`provenance` is the record of who wrote a file and when (gridstrain's
    version, the time, and the versions of the libraries the numbers went
    through), written into every result and summary file.

Memory
    :func:`memory_budget` sets the memory a run may use (default: the least of the
    system's available memory and the control group's limit,
    :func:`available_memory`); :func:`check_fits` refuses a need above it with one
    :class:`MemoryBudgetError` before anything is allocated. :func:`open_series`
    and :func:`read_mask` check the size a file's header declares before decoding
    it, so that a small compressed file declaring a huge image is refused.
"""


from .._runtime.memory import (
    MemoryBudgetError,
    available_memory,
    check_fits,
    memory_budget,
    parse_size,
)

# every module of a format registers it on import: the camera records' has nothing else
# to export
from . import _camera  # noqa: F401
from ._files import (
    MARKER_NAME,
    HDF5Stream,
    OutputDirectory,
    atomic_path,
    hdf5_file,
    hdf5_stream,
    provenance,
    record_outputs,
    space_error,
    sweep_temporary_files,
    write_atomic,
    write_csv,
    write_hdf5,
    written_by_gridstrain,
)

# shared with gridstrain's other folders, not part of the public API
from ._files import check_destination as check_destination
from ._files import make_directory as make_directory
from ._files import watch_outputs as watch_outputs
from ._formats import ImageFormat, register_format, unregister_format
from ._hdf5_attrs import read_hdf5, read_noise_model
from ._loads import LoadsFile, LoadTable, read_loads
from ._numbering import FrameGap, RecordNumbering, record_numbering
from ._readers import IMAGE_EXTENSIONS, close_readers, natural_sort_key, to_luminance
from ._sequences import STATE_ORDERS, StateInputs, natural_order, state_inputs
from ._series import (
    FrameSeries,
    check_saturation,
    check_saturation_limit,
    open_series,
    read_mask,
    roi_mask,
    split_frames,
)
from ._tiff import write_tiff_series

__all__ = [
    "IMAGE_EXTENSIONS",
    "MARKER_NAME",
    "STATE_ORDERS",
    "FrameGap",
    "FrameSeries",
    "HDF5Stream",
    "ImageFormat",
    "LoadTable",
    "LoadsFile",
    "MemoryBudgetError",
    "OutputDirectory",
    "RecordNumbering",
    "StateInputs",
    "atomic_path",
    "available_memory",
    "check_fits",
    "check_saturation",
    "check_saturation_limit",
    "close_readers",
    "hdf5_file",
    "hdf5_stream",
    "memory_budget",
    "natural_order",
    "natural_sort_key",
    "open_series",
    "parse_size",
    "provenance",
    "read_hdf5",
    "read_loads",
    "read_mask",
    "read_noise_model",
    "record_numbering",
    "record_outputs",
    "register_format",
    "roi_mask",
    "space_error",
    "split_frames",
    "state_inputs",
    "sweep_temporary_files",
    "to_luminance",
    "unregister_format",
    "write_atomic",
    "write_csv",
    "write_hdf5",
    "write_tiff_series",
    "written_by_gridstrain",
]

