"""The emulator is the protocol, not this project's reading of it: CESAPI (an independent emScon client, PyPI, MIT;
installed by the dev extra only) connects to tests/emscon_device.py, sets it up in its own way (millimetres) and
measures; its results equal the emulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("CESAPI")

from drivers.sim.rig import SimulatedRig
from tests.emscon_device import EmsconServer


def test_cesapi_client_measures_the_emulator_truth() -> None:
    from CESAPI import packet as tpi
    from CESAPI.command import CommandSync
    from CESAPI.connection import Connection

    rig = SimulatedRig("ur5e", seed=4)
    with EmsconServer(rig, noise=0.0) as server:
        connection = Connection()
        connection.connect(server.host, server.port)
        try:
            command = CommandSync(connection)
            units = tpi.SystemUnitsDataT()
            units.lenUnitType = tpi.ES_LU_Millimeter
            units.angUnitType = tpi.ES_AU_Degree
            command.SetUnits(units)
            command.SetCoordinateSystemType(tpi.ES_CS_RHR)
            settings = tpi.SystemSettingsDataT()
            settings.weatherMonitorStatus = tpi.ES_WMS_ReadOnly  # every other flag off: no transformation
            command.SetSystemSettings(settings)
            command.SetMeasurementMode(tpi.ES_MM_Stationary)
            results = [command.StartMeasurement() for _ in range(2)]
        finally:
            connection.disconnect()
        truths = np.array(server.truths)
        state = (server.units, server.settings, server.coordinates)
    assert state == ((1, 1, 0, 0, 0), (1, 0, 0, 0, 0, 0, 0, 0, 0), 0)  # what CESAPI sent, as the emulator read it
    assert [type(r).__name__ for r in results] == ["SingleMeasResultT"] * 2
    measured = np.array([[r.dVal1, r.dVal2, r.dVal3] for r in results])
    assert np.abs(truths).max() > 0.1  # a real point, metres from the tracker
    np.testing.assert_allclose(measured, truths * 1000.0, rtol=0, atol=1e-9)  # millimetres, exactly the truth
    assert all(r.measMode == tpi.ES_MM_Stationary and r.dStd1 == 0.0 for r in results)
    assert (results[0].dTemperature, results[0].dPressure, results[0].dHumidity) == (20.0, 1013.25, 50.0)
