"""ippc.protocol.values: Java's Double.toString and the valueOf parsers rddlsim reads
values with. Expected strings were produced by OpenJDK 17 (rddlsim's own runtime here)."""

from __future__ import annotations

import math
import struct
from fractions import Fraction

import pytest
from hypothesis import given
from hypothesis import strategies as st
from ippc.protocol import format_value, java_double, parse_java_double, parse_java_int, parse_value

# Double.toString as printed by OpenJDK 17 for hand-picked values: the ones in the
# transcripts, both ends of the plain range, the specials.
JAVA_DOUBLE_TABLE = [
    (10.0, "10.0"),
    (0.0, "0.0"),
    (-0.0, "-0.0"),
    (1.0, "1.0"),
    (-1.5, "-1.5"),
    (100.0, "100.0"),
    (0.1, "0.1"),
    (1.0 / 3, "0.3333333333333333"),
    (0.30000000000000004, "0.30000000000000004"),
    (4.35, "4.35"),
    (123456.789, "123456.789"),
    # seen in the transcripts
    (0.9049894094523613, "0.9049894094523613"),
    (0.9181647320338637, "0.9181647320338637"),
    (0.08819558121972196, "0.08819558121972196"),
    (47.599999999999994, "47.599999999999994"),
    (96.19999999999999, "96.19999999999999"),
    (9.25, "9.25"),
    (2.001, "2.001"),
    (1.75, "1.75"),
    (1080000.0, "1080000.0"),
    (1079655.0, "1079655.0"),
    (2000.0, "2000.0"),
    # the edges of the plain range
    (0.001, "0.001"),
    (1.0e-3, "0.001"),
    (0.002, "0.002"),
    (0.0009999, "9.999E-4"),
    (9.999999999999998e-4, "9.999999999999998E-4"),
    (1.0e-4, "1.0E-4"),
    (9999999.0, "9999999.0"),
    (1.0e7, "1.0E7"),
    (12345678.9, "1.23456789E7"),
    (123456789.0, "1.23456789E8"),
    # scientific
    (-3.5e-5, "-3.5E-5"),
    (1.1e-5, "1.1E-5"),
    (1.234e-5, "1.234E-5"),
    (1.0e-7, "1.0E-7"),
    (1.0e10, "1.0E10"),
    (1.0e16, "1.0E16"),
    (1.0e21, "1.0E21"),
    (1.0e22, "1.0E22"),
    (5e-324, "4.9E-324"),
    (2.2250738585072014e-308, "2.2250738585072014E-308"),
    (1.7976931348623157e308, "1.7976931348623157E308"),
    # specials
    (math.nan, "NaN"),
    (math.inf, "Infinity"),
    (-math.inf, "-Infinity"),
]

# 240 doubles drawn at random (random bit patterns, random decimals of many magnitudes;
# seed 42) and printed by OpenJDK 17's Double.toString: (raw bits in hex, string). Values
# in [1e16, 1e24) are left out on purpose: there JDK <= 18 prints more digits than needed
# (e.g. 5.3916191474798848E16); ippc follows the shortest form JDK 19+ prints.
JDK17_SAMPLE = [
    ("409254e147ae147b", "1173.22"),
    ("3e2135be3b4f5aab", "2.0035E-9"),
    ("4106229800000000", "181331.0"),
    ("4326f8bcf8d6c800", "3.23297E15"),
    ("3f74fbdad7518b0d", "0.005123"),
    ("2476ee3bb027b394", "5.047743880831526E-133"),
    ("cb40dae407cc8f00", "-3.2287845822802156E54"),
    ("fccdd41b5cb324cf", "-1.4883251880350324E293"),
    ("4058a87ae147ae14", "98.6325"),
    ("4072917ced916873", "297.093"),
    ("40192e94ee392e1f", "6.29549"),
    ("4023adc33721d53d", "9.83938"),
    ("a910fa026e364519", "-7.059148365251265E-111"),
    ("3fb2f850df15a4ad", "0.0741015"),
    ("3f8ac14c660a2014", "0.013064"),
    ("dca735b1981964a5", "-2.1593265443801004E138"),
    ("bd2103aa56ca3ed8", "-3.02235E-14"),
    ("4018f50331e3a7db", "6.23927"),
    ("e85c2ec13938944e", "-5.143264101812017E194"),
    ("412b0f1400000000", "886666.0"),
    ("c1c63dbda8000000", "-7.4629E8"),
    ("3ea09013de821f8b", "4.9361E-7"),
    ("41c6f5a7e03c3972", "7.703960964705031E8"),
    ("40a000d1eb851eb8", "2048.41"),
    ("3fac7563596bac20", "0.055583099999999996"),
    ("f0f24cdd43fae2a9", "-1.163733858321877E236"),
    ("422d6be51d226067", "6.3182114449188286E10"),
    ("40170d34c6c8bf3b", "5.762896638872742"),
    ("3f7a97eba55f15ac", "0.006492538921468432"),
    ("4011c46c764adff8", "4.44182"),
    ("405403c577e2b1d5", "80.05892750871801"),
    ("e856e0a7ef9960eb", "-4.1751008151041635E194"),
    ("281b3c6bc2e91a1d", "1.7280858220930083E-115"),
    ("4027c0f9096bb98c", "11.8769"),
    ("41555330bf047cb2", "5590210.98464887"),
    ("815fbd4d431afe3f", "-4.6283255396421024E-302"),
    ("4037046dc5d63886", "23.0173"),
    ("cf6fe4023b64d6f4", "-4.507673387999979E74"),
    ("3e580c71f954e3bd", "2.2397017203723558E-8"),
    ("94ea705354e2bc7f", "-6.433603276305556E-208"),
    ("3e0370c077d35113", "5.657911774950838E-10"),
    ("41cc8379d3a3431a", "9.567569032754853E8"),
    ("c020cefc7a398202", "-8.40427"),
    ("40e620bccccccccd", "45317.9"),
    ("40bb5e4000000000", "7006.25"),
    ("4105fe6000000000", "180172.0"),
    ("be7969dbc0713151", "-9.46727E-8"),
    ("40b505b0a3d70a3d", "5381.69"),
    ("40d7ec999999999a", "24498.4"),
    ("3f4bcbecb08bcfb0", "8.482843123531671E-4"),
    ("3de46781cefda9ef", "1.48461E-10"),
    ("3d99587fc94f4ce7", "5.762944935033397E-12"),
    ("3fed83fb3743632c", "0.922361"),
    ("d3ed5271d9a3b1d4", "-1.9572349393407687E96"),
    ("be37581c0d6b3069", "-5.43524E-9"),
    ("40e5287a1afd609f", "43331.8157946479"),
    ("4122002191e795cf", "589840.7849699798"),
    ("5e64fa9fd055bca2", "5.239293292986567E146"),
    ("3fb691a75cd0bb6f", "0.08816"),
    ("3eab9519441b5922", "8.2202007708579E-7"),
    ("c01ebcce1c58255c", "-7.684380000000001"),
    ("3e6434204af10da1", "3.763217059544901E-8"),
    ("3fb7ffc8a29ba0db", "0.0937467"),
    ("3f8419a47fc63f8c", "0.00981453432976289"),
    ("affd89963562c61d", "-1.594314886111631E-77"),
    ("3fc5e931876188b1", "0.171179"),
    ("408210c16671ae6d", "578.0944336778026"),
    ("3f6389c53b3306e9", "0.0023850300000000002"),
    ("4145fbede24d4058", "2881499.767982524"),
    ("40e63bd666666666", "45534.7"),
    ("3fc23e29307af20f", "0.142522"),
    ("40a040eb851eb852", "2080.46"),
    ("411da4c000000000", "485680.0"),
    ("fac819746e15292e", "-2.799708133154345E283"),
    ("3ea949df5d331c6e", "7.53657952400837E-7"),
    ("e2f6919d30708251", "-5.323363822760853E168"),
    ("40c9634ccccccccd", "12998.6"),
    ("b4bac4742d02fb81", "-1.0916588739024399E-54"),
    ("420bc9c444e37ca6", "1.4918650012435863E10"),
    ("408a407ced916873", "840.061"),
    ("3d0354f43c964465", "8.585066771170319E-15"),
    ("3fb09c46f303983b", "0.0648846"),
    ("84973da10cbf1b7c", "-1.5262794748805737E-286"),
    ("401d37121ab4b72c", "7.30378"),
    ("415728e875420033", "6071201.832153368"),
    ("412045732af72491", "533177.5839168002"),
    ("45d182f1e7f4ad12", "2.1678191570655154E28"),
    ("4265c9e0839236e2", "7.486499790257151E11"),
    ("3eaea6b2681a03c1", "9.134757450042126E-7"),
    ("406d82496a3f266c", "236.07146179517747"),
    ("40ddd7eccccccccd", "30559.7"),
    ("c50e185fe07a283c", "-4.54786E24"),
    ("40f3f4dccccccccd", "81741.8"),
    ("26fd2e94264d4b9f", "7.063111013043762E-121"),
    ("3d32c51d98d3bd04", "6.668437487209642E-14"),
    ("3cb1dfcd706c77a7", "2.4805475038931157E-16"),
    ("3d51a0767441ba18", "2.50492E-13"),
    ("462560f2bec043da", "8.468977172935214E29"),
    ("411ba05000000000", "452628.0"),
    ("bde42e0d0d5b5919", "-1.46828E-10"),
    ("c028113404ea4a8c", "-12.0336"),
    ("40509f95810624dd", "66.4935"),
    ("41b696f59a081595", "3.789920260315793E8"),
    ("41209b0000000000", "544128.0"),
    ("42c348649fc9473c", "4.240329353281447E13"),
    ("d0d4787400610416", "-2.4272120662542083E81"),
    ("bcfbd1430474599a", "-6.176709999999999E-15"),
    ("d3742c1bf51c5bab", "-1.051947624413462E94"),
    ("412864b2662bec17", "799321.19955385"),
    ("bec82dcbc270c9e1", "-2.8823483435799377E-6"),
    ("ceee7cbc5d838349", "-1.6833220877647297E72"),
    ("7f3b90a73859e68c", "7.561264645586675E304"),
    ("3d6686106ae9f9d3", "6.401617160120765E-13"),
    ("6fb0f0e6cb071e84", "1.0273922879525867E230"),
    ("3fa13fe486bc7a2d", "0.0336905874703358"),
    ("421ca98bdd800000", "3.07759E10"),
    ("a37fbf9ea7bdc5be", "-1.0664129396476016E-137"),
    ("35ecc150c364c0d7", "6.148457574601969E-49"),
    ("beab63093062024b", "-8.16192E-7"),
    ("a2c31014434cae1d", "-3.126503671421828E-141"),
    ("cdfa4af74cb474d0", "-4.43033410059899E67"),
    ("195edace52d295dc", "1.772818097152249E-186"),
    ("3ed76fcbbf63b646", "5.587745354624474E-6"),
    ("eb5ffe1194d2be4d", "-1.6434049333428941E209"),
    ("414a6351c3a070e7", "3458723.5283337715"),
    ("3d93d4e101b1a55d", "4.509174306919051E-12"),
    ("40df7d36b7132441", "32244.85492399731"),
    ("42884b0ba3b15a48", "3.338824611371285E12"),
    ("4b55b231015aab4e", "8.312278901230334E54"),
    ("40f09c499999999a", "68036.6"),
    ("3fde34bd76ee73e7", "0.471969"),
    ("3f834aa819e5037a", "0.00941974"),
    ("40b7b0cccccccccd", "6064.8"),
    ("3faac00035afe535", "0.0522461"),
    ("406ce12f1a9fbe77", "231.037"),
    ("266387b07ceb762d", "9.232405076463383E-124"),
    ("52e5898da723df5e", "2.1936145495937832E91"),
    ("3f7a32c3f7911b9c", "0.00639607"),
    ("bd88033bbca752f3", "-2.72992E-12"),
    ("40bbd54f5c28f5c3", "7125.31"),
    ("bffefd0d0678c006", "-1.9367800000000002"),
    ("37c0bc47d0a6913f", "3.842275663316041E-40"),
    ("a1debad309372765", "-1.5380894592443707E-145"),
    ("40d1a88666666666", "18082.1"),
    ("430b64dbe6900000", "9.6384E14"),
    ("3da4f07006d06af6", "9.52205E-12"),
    ("3fa8286f8ad2567a", "0.0471835"),
    ("e0ef215745849c9d", "-8.548111374073182E158"),
    ("401560639d5e4a38", "5.34413"),
    ("bdd791efd5b24ddd", "-8.57474E-11"),
    ("40a9383851eb851f", "3228.11"),
    ("3ea7028a0fca5ee0", "6.857490287446491E-7"),
    ("3f80815783749427", "0.0080592"),
    ("42b6299805ff0000", "2.43679E13"),
    ("6db91afdcbe717a5", "3.54490496193015E220"),
    ("3e5cd6474aa88ccc", "2.6856572669009448E-8"),
    ("3fe36f8f041461b7", "0.607368"),
    ("401d0ded288ce704", "7.2636"),
    ("40ee249333333333", "61732.6"),
    ("404ecf1de69ad42c", "61.6181"),
    ("c0f36ee000000000", "-79598.0"),
    ("c510ac9b08682a8c", "-5.03948E24"),
    ("3fefb352a8438088", "0.99064"),
    ("7efbb0d0fa8b37a7", "4.747329815532461E303"),
    ("3fe1c2e126202539", "0.555039"),
    ("e81afaff9ea9e293", "-3.0774190009392806E193"),
    ("82a439612a7847d7", "-6.184780770815741E-296"),
    ("40cce00ccccccccd", "14784.1"),
    ("3e055cc87ee14d33", "6.217286666056272E-10"),
    ("3fe4224edf612407", "0.629188"),
    ("d98d01bd5a04af29", "-2.3968894147955785E123"),
    ("40abc67ae147ae14", "3555.24"),
    ("3d9599a8c9affa55", "4.911324082984069E-12"),
    ("3fd86dc5d6388659", "0.3817"),
    ("3faab917e42253e8", "0.0521934"),
    ("3fb0707290b7643f", "0.06421581299891076"),
    ("3d2e10a9b923b828", "5.340632784105887E-14"),
    ("3f42cd88c59d13de", "5.73818E-4"),
    ("b7a0d50443f91e6e", "-9.661149490357448E-41"),
    ("28e09d9b6665c5f8", "8.63632579521167E-112"),
    ("42d09dd55494c000", "7.30803E13"),
    ("c0bdb96666666667", "-7609.400000000001"),
    ("3d2343fcceba54e1", "3.422253820201652E-14"),
    ("c101e01800000000", "-146435.0"),
    ("37cf51c0f34ed0fe", "7.1905702174578876E-40"),
    ("4150f71d80000000", "4447350.0"),
    ("becddaf56f2e6740", "-3.5590299999999997E-6"),
    ("463b00cfc53036f5", "2.1394115667253983E30"),
    ("40467894df319f79", "44.94204320834155"),
    ("400b78ef34d6a162", "3.43405"),
    ("3cd0aa8af5d15bd0", "9.251589974542508E-16"),
    ("c18640ec80000000", "-4.66692E7"),
    ("3ffc6d5cfaacd9e9", "1.7767000000000002"),
    ("411a194400000000", "427601.0"),
    ("42002dee497d9bb7", "8.686258479701033E9"),
    ("3fc00a7c5ac471b4", "0.12532"),
    ("bfeb9904b3c3e74b", "-0.862429"),
    ("4042159e83e425af", "36.1689"),
    ("70828727e0324a48", "9.204793924153031E233"),
    ("42c54ffead7e00e8", "4.686663876505781E13"),
    ("415d6e8a80000000", "7715370.0"),
    ("3fc6a808c8259e1f", "0.177003"),
    ("41936d2ed657f7d3", "8.148062958590631E7"),
    ("3f600165782bf51a", "0.0019537908386825344"),
    ("40174641b328b6d8", "5.81861"),
    ("40c01bf47ae147ae", "8247.91"),
    ("3d044629e9aadb4b", "9.003498852251135E-15"),
    ("3fb4ecb8fb5eb08f", "0.0817371"),
    ("56c404b3a0c050fd", "9.40279695297651E109"),
    ("c29ed04d5d700000", "-8.47E12"),
    ("4116502800000000", "365578.0"),
    ("3fda2e275ab7dc7b", "0.409067"),
    ("41bec1d53bdd0526", "5.160195158633598E8"),
    ("3f87fec4969d65d7", "0.0117164"),
    ("cb24d183d0f79ee1", "-9.970041296964044E53"),
    ("4142b5d3fd449a1c", "2452391.9786560666"),
    ("e6967d3574aff66", "3.0480520176781444E-239"),
    ("40edba4ccccccccd", "60882.4"),
    ("415a04d700000000", "6820700.0"),
    ("e142370a1652747", "7.550387584260529E-241"),
    ("fd0d77a5a6a3a546", "-2.3524867048623503E294"),
    ("3e907eb571b3d576", "2.45794E-7"),
    ("d1b182ba58d58e77", "-3.40174065570901E85"),
    ("4b26b6027e72e708", "1.0876396489378205E54"),
    ("bd02dd3e07c9eab0", "-8.3774E-15"),
    ("40be52cf5c28f5c3", "7762.81"),
    ("9cf626841148ef8", "1.9933687821768918E-261"),
    ("3ed374c0fc7415b6", "4.638688501095434E-6"),
    ("41c0e10f68000000", "5.6637E8"),
    ("27ecefdd9ab992e0", "2.295011247370926E-116"),
    ("422c102bf3000000", "6.02652E10"),
    ("f1b5d710f37bbc8c", "-5.688676485984402E239"),
    ("c983550f43b4da46", "-1.379596471389125E46"),
    ("3d712b41d37c4ff1", "9.759431336995485E-13"),
    ("3fb67ad58933f0c8", "0.0878118"),
    ("3f98f9f44d445671", "0.024391"),
    ("4125e50d23f1864c", "717446.5702020614"),
    ("40e1f5599999999a", "36778.8"),
    ("3e606593fb519960", "3.0541400000000004E-8"),
    ("42a126c19b21536b", "9.429077299369709E12"),
]


def _from_bits(hex_bits: str) -> float:
    return float(struct.unpack(">d", int(hex_bits, 16).to_bytes(8, "big"))[0])


@pytest.mark.parametrize(("value", "expected"), JAVA_DOUBLE_TABLE)
def test_java_double_table(value: float, expected: str) -> None:
    assert java_double(value) == expected


def test_java_double_matches_jdk17_sample() -> None:
    wrong = [(b, s, java_double(_from_bits(b))) for b, s in JDK17_SAMPLE]
    wrong = [w for w in wrong if w[1] != w[2]]
    assert wrong == []
    assert len(JDK17_SAMPLE) == 240


def test_java_double_differs_from_jdk17_only_where_jdk17_is_not_shortest() -> None:
    # JDK 17 prints 1.9999999999999998E23 and 9.999999999999999E22 here; JDK 19+ and
    # ippc print the shortest decimal that reads back as the same double.
    assert java_double(2e23) == "2.0E23"
    assert java_double(1e23) == "1.0E23"
    assert java_double(5.3916191474798848e16) == "5.391619147479885E16"


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_java_double_reads_back_exactly(x: float) -> None:
    text = java_double(x)
    assert parse_java_double(text) == x
    assert math.copysign(1.0, parse_java_double(text)) == math.copysign(1.0, x)
    # Java's shape: a point always, an exponent only outside [1e-3, 1e7), no '+'
    assert "." in text and "+" not in text and "e" not in text
    assert ("E" in text) == (x != 0 and not 1e-3 <= abs(x) < 1e7)
    mantissa = text.split("E")[0].lstrip("-")
    if "E" in text:
        assert 1 <= float(mantissa) < 10


@given(st.floats(allow_nan=False, allow_infinity=False).filter(lambda v: v != 0))
def test_java_double_is_shortest_with_two_digits_minimum(x: float) -> None:
    # No decimal with fewer significant digits reads back as x (Java keeps >= 2 digits).
    text = java_double(x)
    mantissa, _, _ = text.lstrip("-").partition("E")
    digits = mantissa.replace(".", "").lstrip("0").rstrip("0") or "0"
    shortest = repr(x).lstrip("-").split("e")[0].replace(".", "").strip("0")
    assert len(digits) <= max(len(shortest), 2)
    # and it is the closest such decimal: its error is at most Python's repr's error
    exact = Fraction(x)
    assert abs(Fraction(text.replace("E", "e")) - exact) <= abs(Fraction(repr(x)) - exact)


def test_format_value() -> None:
    assert format_value(True) == "true"
    assert format_value(False) == "false"
    assert format_value(0) == "0"
    assert format_value(2) == "2"
    assert format_value(-7) == "-7"
    assert format_value(2.0) == "2.0"
    assert format_value(1e-4) == "1.0E-4"
    assert format_value("@left") == "@left"
    assert format_value("c1") == "c1"
    with pytest.raises(TypeError):
        format_value(None)
    with pytest.raises(TypeError):
        format_value(object())


def test_format_value_numpy_scalars() -> None:
    np = pytest.importorskip("numpy")
    assert format_value(np.bool_(True)) == "true"
    assert format_value(np.bool_(False)) == "false"
    assert format_value(np.int64(3)) == "3"
    assert format_value(np.int32(-3)) == "-3"
    assert format_value(np.float64(0.5)) == "0.5"
    assert format_value(np.float64(1e7)) == "1.0E7"
    assert format_value(np.float32(0.5)) == "0.5"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("true", True),
        ("TRUE", True),
        ("True", True),
        ("tRuE", True),
        ("false", False),
        ("yes", False),
        ("1", False),
        (" true ", False),
        ("", False),
    ],
)
def test_parse_bool_is_boolean_valueof(text: str, expected: bool) -> None:
    assert parse_value(text, "bool") is expected


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("1", 1),
        ("+1", 1),
        ("-1", -1),
        ("01", 1),
        ("0", 0),
        ("2147483647", 2**31 - 1),
        ("-2147483648", -(2**31)),
        ("\u0663", 3),
    ],  # Java accepts any Unicode digit
)
def test_parse_int(text: str, expected: int) -> None:
    value = parse_value(text, "int")
    assert value == expected and type(value) is int


@pytest.mark.parametrize(
    "text",
    [
        "",
        " 1",
        "1 ",
        "1.0",
        "+",
        "-",
        "0x1",
        "1_0",
        "+-1",
        "2147483648",
        "-2147483649",
        "1e3",
        "abc",
    ],
)
def test_parse_int_rejects_what_integer_valueof_rejects(text: str) -> None:
    with pytest.raises(ValueError):
        parse_value(text, "int")


def test_parse_java_long() -> None:
    assert parse_java_int("2147483648", bits=64) == 2**31
    assert parse_java_int("-704", bits=64) == -704
    assert parse_java_int("9223372036854775807", bits=64) == 2**63 - 1
    with pytest.raises(ValueError):
        parse_java_int("9223372036854775808", bits=64)
    with pytest.raises(ValueError):
        parse_java_int("1079615.0", bits=64)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("1", 1.0),
        (".25", 0.25),
        ("1.0E-3", 0.001),
        ("1e3", 1000.0),
        ("1e+3", 1000.0),
        ("1.", 1.0),
        ("+.5", 0.5),
        ("-.5e-2", -0.005),
        ("00.5", 0.5),
        (" 1.5 ", 1.5),
        ("\t2\n", 2.0),
        ("\x01 1 \x02", 1.0),  # String.trim strips every char <= U+0020
        ("1.0d", 1.0),
        ("1f", 1.0),
        ("1.F", 1.0),
        ("1e3f", 1000.0),
        ("1d ", 1.0),
        ("0x1p3", 8.0),
        ("0X1.8P1", 3.0),
        ("0x.8p1", 1.0),
        ("0x1p3d", 8.0),
        ("-0x1p3", -8.0),
        ("Infinity", math.inf),
        ("+Infinity", math.inf),
        ("-Infinity", -math.inf),
        ("1E400", math.inf),
        ("1E-400", 0.0),
        ("0.9181647320338637", 0.9181647320338637),
        ("-3.1591695524875245", -3.1591695524875245),
    ],
)
def test_parse_real_is_double_valueof(text: str, expected: float) -> None:
    value = parse_value(text, "real")
    assert type(value) is float and value == expected


def test_parse_real_nan() -> None:
    for text in ("NaN", "+NaN", "-NaN", " NaN "):
        value = parse_value(text, "real")
        assert isinstance(value, float) and math.isnan(value)


@pytest.mark.parametrize(
    "text",
    [
        "",
        ".",
        "e3",
        "1e",
        "1e+",
        "0x1.8",
        "0x",
        "inf",
        "nan",
        "infinity",
        "InfinityD",
        "Infinityx",
        "1_0",
        "abc",
        "1.0E-3 x",
        "1 d",
        "1e1.5",
        "++1",
        "\u00a01",
        "\u0663",
    ],
)
def test_parse_real_rejects_what_double_valueof_rejects(text: str) -> None:
    with pytest.raises(ValueError):
        parse_value(text, "real")


def test_parse_enum_and_object_are_text_as_is() -> None:
    assert parse_value("@left", "enum") == "@left"
    assert parse_value(" right ", "enum") == " right "
    assert parse_value("$c2", "object") == "$c2"
    with pytest.raises(ValueError):
        parse_value("1", "float")
