"""Mass properties of meshes against analytic solids."""

import numpy as np
import pytest
import trimesh

from rose_usd.core.inertia import mass_properties


def test_box_inertia_is_analytic():
    """A 0.1 x 0.2 x 0.3 m box of 700 kg/m^3 has I = m/12 (b^2 + c^2) about each axis."""
    box = trimesh.creation.box([0.1, 0.2, 0.3])
    box.apply_translation([0.5, -0.2, 0.15])
    mp = mass_properties(box.vertices, box.faces, 700.0)
    m = 700.0 * 0.1 * 0.2 * 0.3
    assert mp.mass_kg == pytest.approx(m, rel=1e-9)
    np.testing.assert_allclose(mp.center_of_mass_m, [0.5, -0.2, 0.15], atol=1e-12)
    expected = sorted([m / 12 * (0.2**2 + 0.3**2), m / 12 * (0.1**2 + 0.3**2), m / 12 * (0.1**2 + 0.2**2)])
    np.testing.assert_allclose(mp.diagonal_inertia, expected, rtol=1e-9)
    assert np.linalg.det(mp.principal_axes) == pytest.approx(1.0)


def test_cylinder_inertia_within_one_percent():
    """A 128-gon cylinder matches the analytic cylinder to 1 %: Izz = m r^2/2, Ixx = m(3r^2 + h^2)/12."""
    r, h, rho = 0.04, 0.12, 1000.0
    cyl = trimesh.creation.cylinder(radius=r, height=h, sections=128)
    mp = mass_properties(cyl.vertices, cyl.faces, rho)
    m = rho * np.pi * r**2 * h
    assert mp.mass_kg == pytest.approx(m, rel=0.01)
    np.testing.assert_allclose(
        sorted(mp.diagonal_inertia),
        sorted([m * r**2 / 2, m * (3 * r**2 + h**2) / 12, m * (3 * r**2 + h**2) / 12]),
        rtol=0.01,
    )


def test_rotated_box_principal_axes():
    """The principal frame of a rotated box recovers the inertia tensor: R diag(I) R^T."""
    box = trimesh.creation.box([0.1, 0.2, 0.3])
    box.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(5).random(3)))
    mp = mass_properties(box.vertices, box.faces, 500.0)
    np.testing.assert_allclose(
        mp.principal_axes @ np.diag(mp.diagonal_inertia) @ mp.principal_axes.T, mp.inertia_com, atol=1e-12
    )


@pytest.mark.filterwarnings("ignore:invalid value encountered in divide")
def test_open_mesh_is_rejected():
    """A mesh that encloses no volume is refused."""
    plane = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    with pytest.raises(ValueError, match="volume"):
        mass_properties(plane.vertices, plane.faces, 1000.0)


def test_hollow_sphere_shell_matches_the_analytic_value():
    """A 3 mm wall inside a 5 cm sphere: mass rho * 4/3 pi (R^3 - r^3), I = 2/5 m (R^5 - r^5) / (R^3 - r^3)."""
    import trimesh

    from rose_usd.core.inertia import shell_mass_properties

    big, wall, rho = 0.05, 0.003, 1000.0
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=big)
    props = shell_mass_properties(sphere.vertices, sphere.faces, rho, wall)
    small = big - wall
    mass = rho * 4.0 / 3.0 * np.pi * (big**3 - small**3)
    inertia = 0.4 * mass * (big**5 - small**5) / (big**3 - small**3)
    assert props.mass_kg == pytest.approx(mass, rel=0.01)
    assert props.diagonal_inertia == pytest.approx([inertia] * 3, rel=0.01)
    assert np.linalg.norm(props.center_of_mass_m) < 1e-6
